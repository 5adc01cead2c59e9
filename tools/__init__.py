"""The snan-hil command-line interface."""
