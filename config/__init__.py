"""Configuration files and ``--set`` overrides: the YAML 1.2 loader of typed dataclass trees
(``loader``). The config classes themselves live with their layer. Imports no layer."""
