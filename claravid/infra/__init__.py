"""Infrastructure that ``train/``, ``eval/`` and ``models/`` share, none of it data or model.

Command-line conventions (``cli``), output checks and atomic writes (``files``), errors users
see (``errors``), job-array shards (``shards``), distributed helpers (``distributed``), the
precision policy (``precision``), packaged resources (``resources``), the cache folder rule
(``cachedir``) and the memory available to new allocations (``memory``).
Imports nothing else of the project: every other layer may import it.
"""
