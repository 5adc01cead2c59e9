"""Host-board protocol: frames, messages, reliable link, transports, legacy line codec."""
