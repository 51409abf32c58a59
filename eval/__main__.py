"""``python -m eval`` (and ``torchrun ... -m eval``): the ``claravid-eval`` command."""

from eval.cli import main

raise SystemExit(main())
