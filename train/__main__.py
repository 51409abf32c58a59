"""``python -m claravid.train`` (and ``torchrun ... -m claravid.train``): ``claravid-train``."""

from claravid.train.cli import main

raise SystemExit(main())
