"""``claravid-train --config CONFIG [key=value ...] [--resume]`` (``python -m claravid.train``).

``--data DIR`` is ``data.root=DIR`` and ``-o DIR`` ``out_dir=DIR`` (the paths as given: a ``${``
in them is no interpolation), ``--workers N`` ``data.num_workers=N``, ``--precision P``
``train.precision=P`` and ``--no-progress`` ``log.progress=false``: the flags every console
script shares. ``key=value`` overrides may stand before or after the flags.

CONFIG is a YAML file or the name of a shipped config (``demo``, ``claravid_dpt_vitl14``, ...).
Multi-GPU: ``torchrun --nproc_per_node=N -m claravid.train --config ...``. The last lines say
where the results are and how to evaluate and export them.
"""

from __future__ import annotations

import argparse
import shlex
import sys

from claravid.infra.cli import (
    UsageError,
    add_data_flag,
    add_debug_flag,
    add_output_flag,
    add_precision_flag,
    add_progress_flag,
    non_negative_int,
    run_cli,
)
from claravid.infra.resources import shipped_names

PROG = "claravid-train"


class _IntermixedParser(argparse.ArgumentParser):
    """``key=value`` overrides before, between or after the flags (``--resume out_dir=x``):
    argparse alone takes positionals in one run only."""

    def parse_args(self, args=None, namespace=None):
        return self.parse_intermixed_args(args, namespace)


def build_parser() -> argparse.ArgumentParser:
    configs = ", ".join(n for n in shipped_names() if n != "augment")
    parser = _IntermixedParser(
        prog=PROG,
        description="Train a segmenter (a DINOv2 or DINOv3 backbone, frozen by default, and a "
        "DPT head) from a YAML config. --data, -o, --workers, --precision and --no-progress are "
        "the config's data.root, out_dir, data.num_workers, train.precision and log.progress "
        "(unset: the config's).",
        epilog="Examples: claravid-train --config demo --resume; claravid-train --config "
        "claravid_dpt_vitl14 --data /data/claravid -o runs/vitl14 train.steps=20000",
    )
    parser.add_argument("--config", required=True, help=f"YAML path or shipped name ({configs})")
    parser.add_argument("overrides", nargs="*", metavar="key=value", help="dotted overrides")
    parser.add_argument(
        "--resume",
        action="store_true",
        help="continue out_dir/last.pt (a fresh start when there is none)",
    )
    add_data_flag(parser)
    add_output_flag(parser)
    parser.add_argument(
        "--workers",
        type=non_negative_int,
        metavar="N",
        help="worker processes for data loading, the same as data.num_workers=N "
        "(default: the config's; 0: all in this process)",
    )
    add_precision_flag(parser)
    add_progress_flag(parser)
    add_debug_flag(parser)
    return parser


def _run(args: argparse.Namespace) -> int:
    from claravid.train.config import load_config  # heavy imports after argparse: --help stays fast
    from claravid.train.loop import TrainingDiverged, train

    cfg = load_config(args.config, overrides(args))
    try:
        result = train(cfg, resume=args.resume)
    except TrainingDiverged as exc:
        print(f"{PROG}: stopped: {exc}", file=sys.stderr)
        return 1
    if not _is_main():
        return 0
    out = result.out_dir
    if result.best_miou is not None:
        bins = result.last_val.get("miou_bins") or {}
        per_bin = ", ".join(
            f"{k} {v:.3f}" if v is not None else f"{k} n/a" for k, v in bins.items()
        )
        print(
            f"best val mIoU {result.best_miou:.3f} at step {result.best_step}; last validation "
            f"(step {result.last_val.get('step')}): mIoU {_num(result.last_val.get('miou'))}"
            + (f", per delentropy bin: {per_bin}" if per_bin else "")
        )
    drawn = ", budget.json" if (out / "budget.json").is_file() else ""  # a label budget's images
    print(f"results in {out}: config.yaml, metrics.jsonl, curves.png, last.pt, best.pt{drawn}")
    best = out / "best.pt" if (out / "best.pt").is_file() else out / "last.pt"
    # claravid-eval reads the validation data, palette, split and windows from the checkpoint.
    # Shell-quoted: a path with spaces is pasted back as one argument.
    q = shlex.quote
    print(f"evaluate: claravid-eval --checkpoint {q(str(best))} --output {q(str(out / 'report'))}")
    onnx = q(str(best.with_suffix(".onnx")))
    print(f"export:   claravid-export --checkpoint {q(str(best))} --output {onnx}")
    return 0


def overrides(args: argparse.Namespace) -> list[str]:
    """The ``key=value`` overrides with ``--data``, ``-o``, ``--workers``, ``--precision`` and
    ``--no-progress`` spelled as keys."""
    given = list(args.overrides)
    flags = []
    for flag, path, key in (("--data", args.data, "data.root"),
                            ("-o/--output", args.output, "out_dir")):  # fmt: skip
        if path is not None:
            # YAML single quotes keep the path as given; OmegaConf reads ``\${`` as a literal
            # ``${``.
            quoted = str(path).replace("'", "''").replace("${", "\\${")
            flags.append((flag, key, f"'{quoted}'"))
    if args.precision is not None:
        flags.append(("--precision", "train.precision", args.precision))
    if getattr(args, "workers", None) is not None:
        flags.append(("--workers", "data.num_workers", str(args.workers)))
    if args.no_progress:
        flags.append(("--no-progress", "log.progress", "false"))
    for flag, key, value in flags:
        if any(o.split("=", 1)[0].strip() == key for o in given):
            raise UsageError(f"{flag} and {key}= both given: give one")
        given.append(f"{key}={value}")
    return given


def _num(value: float | None) -> str:
    return "n/a" if value is None else f"{value:.3f}"


def _is_main() -> bool:
    import torch.distributed as dist

    return not (dist.is_available() and dist.is_initialized()) or dist.get_rank() == 0


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``claravid-train``."""
    return run_cli(PROG, _run, build_parser(), argv)


if __name__ == "__main__":
    raise SystemExit(main())
