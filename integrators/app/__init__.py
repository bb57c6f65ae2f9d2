"""The application: command line, progressive rendering, image files, the run record."""
