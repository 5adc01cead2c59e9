"""snan-hil: spiking neuron-astrocyte navigation agent on memristor hardware.

Sub-packages: ``host`` (agent, environments, experiments, HIL runs), ``protocol`` (frames,
messages, link, transports), ``crossbar_model`` (device and array physics), ``firmware_emu``
(board emulator), ``calibration`` (weight mapping, write-and-verify), ``tools`` (the CLI).
"""

__version__ = "0.1.0"
