"""``python -m claravid.eval`` (and ``torchrun ... -m claravid.eval``): ``claravid-eval``."""

from claravid.eval.cli.evaluate import main

raise SystemExit(main())
