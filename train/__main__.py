"""``python -m train`` (and ``torchrun ... -m train``): the ``claravid-train`` command."""

from train.cli import main

raise SystemExit(main())
