"""Hardware-in-the-loop SNAN runs: route training, crossbar synapse back-end, the four-scenario
comparison (paper Fig. 10C) and the speed/energy report (Fig. 10D). See docs/hil.md."""
