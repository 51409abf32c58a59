"""``python -m claravid.eval`` (and ``torchrun ... -m claravid.eval``): ``claravid-eval``."""

from claravid.eval.cli import main

raise SystemExit(main())
