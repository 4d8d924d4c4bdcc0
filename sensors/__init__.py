"""sensors package (see DESIGN.md)."""
