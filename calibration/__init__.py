"""Weight <-> conductance mapping, read-chain calibration, two-stage write-and-verify.

Entry points (docs/calibration.md):

* :func:`~snan_hil.calibration.weights_io.load_weight_set` — load/validate weights files;
* :func:`~snan_hil.calibration.programmer.program_weights` — the ``program-weights`` job;
* :class:`~snan_hil.calibration.layout.Layout` — synapse placement + calibration (JSON);
  ``Layout.load(path)`` (default paths: :mod:`snan_hil.board.files`),
  ``weight_from_column_code(adc, row_code)``;
* :mod:`~snan_hil.calibration.readback` — read weights back, retention.
"""
