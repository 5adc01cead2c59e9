"""Files on disk: atomic writes and permissions (``atomicio``), outputs checked before the work
(``outputs``), the user's data folder (``userdata``). Imports no layer."""
