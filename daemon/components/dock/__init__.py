# The charging dock: where it is, going home to it, leaving it.
