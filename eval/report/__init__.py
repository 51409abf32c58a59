"""Report: the JSON built from a per-image table, and the folders written from it.

``build`` (the report's JSON), ``files`` (``report.json`` and ``confusions.npz``, written
atomically and read back checked), ``folder`` (the report folder with ``report.md`` and the
plots), ``markdown``, ``plots`` and ``compare`` (the ``compare`` folder).
"""
