"""What every layer shares: user errors (one line, exit 2), the write-pulse polarity, progress
events of long jobs. Imports no layer."""
