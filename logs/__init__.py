"""logs package (see DESIGN.md)."""
