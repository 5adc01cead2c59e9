"""Weight <-> conductance mapping, read-chain calibration, two-stage write-and-verify.

Entry points (docs/calibration.md):

* :func:`~snan_hil.calibration.weights_io.load_weight_set` — load/validate weights files;
* :class:`~snan_hil.calibration.programmer.ProgramJob` — the ``program-weights`` job (the
  job runner's); :func:`~snan_hil.calibration.programmer.program_on_bench` the programming
  on a cell bench, :func:`~snan_hil.calibration.programmer.program_weights` on a session;
* :class:`~snan_hil.calibration.layout.Layout` — synapse placement + calibration (JSON);
  ``Layout.load(path)`` (default paths: :mod:`snan_hil.board.files`),
  ``weight_from_column_code(adc, row_code)``;
* :mod:`~snan_hil.calibration.readback` — read weights back, retention.
"""
