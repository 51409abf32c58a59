"""The ignore index: the train id of pixels no measure counts and the loss ignores.

It is ClaraVid's unlabeled id (``claravid.io.layout.UNLABELED_ID``, 255): every palette maps its
ignored classes to it and the training crops are padded with it, so the data layer, the loss and
every evaluation measure agree on one number. Standard library only, so the numpy-only analysis
layer may import it.
"""

from __future__ import annotations

from claravid.io.layout import UNLABELED_ID

#: The train id no measure counts and the loss ignores (255).
IGNORE_INDEX: int = UNLABELED_ID
