"""The application: the command line, the replay pipeline and its detection worker, the
report and the overlay. Built on the library; nothing in the library imports it."""
