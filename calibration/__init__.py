"""Weight-conductance mapping, write-and-verify programming, read-chain calibration."""
