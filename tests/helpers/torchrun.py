"""The command prefix of a real ``torchrun`` on CPU for tests: N local processes, gloo.

``--standalone`` rendezvouses on the fixed port 29400, so two test runs at once (CI beside a
developer's run) collide; a free port picked here does not.
"""

import socket
import sys


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def torchrun(nproc: int = 2) -> list[str]:
    """``python -m torch.distributed.run`` for ``nproc`` processes on this machine."""
    return [
        sys.executable, "-m", "torch.distributed.run", "--nnodes=1",
        f"--nproc_per_node={nproc}", "--rdzv-backend=c10d",
        f"--rdzv-endpoint=127.0.0.1:{free_port()}",
    ]  # fmt: skip
