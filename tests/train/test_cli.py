"""claravid-train's shared flags: `-o` is `out_dir=`, `--no-progress` is `log.progress=false`."""

from claravid.train import load_config
from claravid.train.cli import build_parser, main, overrides


def test_output_and_no_progress_flags_set_the_config_keys(tmp_path):
    out = tmp_path / "it's a run: 1"  # quote, colon, space: YAML must keep it a plain string
    args = build_parser().parse_args(["--config", "demo", "-o", str(out), "--no-progress"])
    cfg = load_config("demo", overrides(args))
    assert cfg.out_dir == str(out) and cfg.log.progress is False
    plain = load_config("demo", overrides(build_parser().parse_args(["--config", "demo"])))
    assert plain.out_dir == "runs/demo/train" and plain.log.progress is True


def test_a_flag_and_its_key_together_are_one_line(tmp_path, capsys):
    for argv, message in [
        (["-o", str(tmp_path), f"out_dir={tmp_path}"], "-o/--output and out_dir= both given"),
        (["--no-progress", "log.progress=true"], "--no-progress and log.progress= both given"),
    ]:
        assert main(["--config", "demo", *argv]) == 2
        err = capsys.readouterr().err.strip()
        assert err == f"claravid-train: error: {message}: give one"
    assert not any(tmp_path.iterdir())  # refused before anything was written


def test_overrides_after_a_flag_and_workers(tmp_path):
    """``--resume out_dir=x``: a key=value after a flag is an override, not an error;
    ``--workers N`` is ``data.num_workers=N``."""
    args = build_parser().parse_args(
        ["--config", "demo", "--resume", f"out_dir={tmp_path}", "--workers", "0", "train.steps=3"]
    )
    assert args.resume is True
    cfg = load_config("demo", overrides(args))
    assert cfg.out_dir == str(tmp_path) and cfg.train.steps == 3 and cfg.data.num_workers == 0
    assert main(["--config", "demo", "--workers", "0", "data.num_workers=1"]) == 2


def test_an_output_path_with_a_dollar_brace_is_the_path(tmp_path):
    out = tmp_path / "${train.steps}" / "x'${oops"
    args = build_parser().parse_args(["--config", "demo", "-o", str(out)])
    assert load_config("demo", overrides(args)).out_dir == str(out)
