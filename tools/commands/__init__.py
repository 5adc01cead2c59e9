"""Sub-commands of snan-hil; each module here defines one (auto-discovered)."""
