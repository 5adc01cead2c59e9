"""What is kept of a board's life: the chip history database (``history``). Imports no layer."""
