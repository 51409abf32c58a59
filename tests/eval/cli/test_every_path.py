"""Fixes that must hold on every path that reaches them (issue 24 §1 items 2 and 3): ``merge``
and ``compare`` never load torch, and a bootstrap that cannot fit in memory is refused before
anything is allocated, in every mode of ``claravid-eval`` and every function of the API."""

import json
import subprocess
import sys

import pytest

# The console script as pip installs it: the entry point is loaded by its declared name, in a
# fresh interpreter, and what it imported is looked at once main() has returned.
_ENTRY_POINT = """
import sys
from importlib.metadata import entry_points

(script,) = [e for e in entry_points(group="console_scripts") if e.name == "claravid-eval"]
code = script.load()(sys.argv[1:])
print(json.dumps({"code": code, "torch": "torch" in sys.modules}))
"""


def _console_script(*argv):
    out = subprocess.run(
        [sys.executable, "-c", "import json\n" + _ENTRY_POINT, *map(str, argv)],
        capture_output=True,
        text=True,
        check=True,
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


@pytest.mark.parametrize("mode", ["merge", "compare"])
def test_merge_and_compare_never_load_torch(label_map_reports, tmp_path, mode):
    tmp = label_map_reports["tmp"]
    if mode == "merge":
        argv = ["merge", tmp / "a", "--bins", "2", "-o", tmp_path / "m"]
    else:
        argv = ["compare", tmp / "a", tmp / "b", "-o", tmp_path / "c"]
    done = _console_script(*argv, "--bootstrap", "100", "--no-progress")
    assert done == {"code": 0, "torch": False}
    assert (tmp_path / ("m" if mode == "merge" else "c")).is_dir()  # the work was done


# --- item 3: a bootstrap that does not fit is refused first, on every path ---------------------

#: The memory the tests pretend the machine has available (MemAvailable, which the check reads).
FREE = 100 * 2**20
#: 2 million resamples: their draw counts alone (36 images in 8 block clusters, int32: 64 MB)
#: fit in FREE, the bootstrap as a whole (the statistics of every resample, their sorted copies)
#: does not. Checking the draw counts alone lets the run allocate and compute past the check.
HUGE = "2000000"


@pytest.fixture
def little_memory(monkeypatch):
    from claravid.infra import memory

    meminfo = f"MemTotal: {64 * FREE // 1024} kB\nMemAvailable: {FREE // 1024} kB\n"
    monkeypatch.setattr(memory, "_read_meminfo", lambda: meminfo)


def _refused(capsys):
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.startswith("claravid-eval: error:")]
    assert len(lines) == 1 and "Traceback" not in err, err
    assert "GiB" in lines[0] and "lower --bootstrap" in lines[0], lines[0]
    assert "resamples" in lines[0], lines[0]


def _scores_csv(reps, folder):
    csv = folder / "scores.csv"
    rows = [f"{f.paths['rgb']},{i}" for i, f in enumerate(reps["ds"].frames)]
    csv.write_text("path,err\n" + "\n".join(rows) + "\n")
    return csv


@pytest.mark.parametrize("mode", ["predictions", "tiles", "merge", "compare", "unpaired", "scores"])
def test_a_bootstrap_too_large_is_one_line_in_every_mode(
    label_map_reports, tmp_path, capsys, little_memory, mode
):
    from claravid.eval.cli.evaluate import main

    reps, tmp = label_map_reports, label_map_reports["tmp"]
    out = tmp_path / "out"
    half = tmp_path / "half.txt"
    half.write_text("\n".join(f.key for f in reps["ds"].frames[::2]) + "\n")
    argv = {
        "predictions": ["--predictions", tmp / "pred_a", *reps["common"][:-2]],
        "tiles": ["--predictions", tmp / "pred_a", *reps["common"][:-2], "--tiles", "32"],
        "merge": ["merge", tmp / "a"],
        "compare": ["compare", tmp / "a", tmp / "b"],
        "unpaired": ["compare", tmp / "a", tmp / "half"],
        "scores": ["scores", _scores_csv(reps, tmp_path), "--data", reps["root"],
                   "--split", "all"],
    }[mode]  # fmt: skip
    if mode == "unpaired":  # A over half the frames: compared with B unpaired
        common = [str(half) if a == "all" else a for a in reps["common"]]
        assert main(["--predictions", str(tmp / "pred_b"), *common, "-o", str(tmp_path / "h")]) == 0
        argv = ["compare", tmp / "a", tmp_path / "h"]
        capsys.readouterr()
    assert main([*map(str, argv), "--bootstrap", HUGE, "-o", str(out)]) == 2
    _refused(capsys)
    assert not out.exists()


def test_a_model_evaluation_is_refused_before_the_inference(
    model_files, tmp_path, capsys, little_memory
):
    from claravid.eval.cli.evaluate import main

    preds = tmp_path / "preds"
    argv = ["--checkpoint", str(model_files["checkpoint"]), "--split", "all", "--bootstrap",
            HUGE, "--save-predictions", str(preds), "-o", str(tmp_path / "out"),
            "--no-progress"]  # fmt: skip
    assert main(argv) == 2
    _refused(capsys)
    # No label map was predicted: the check came before the model ran.
    assert not preds.exists() or not any(preds.rglob("*.png"))


@pytest.mark.parametrize("call", ["evaluate", "merge", "compare", "score_metrics", "build_report"])
def test_a_bootstrap_too_large_is_refused_by_the_python_api(
    label_map_reports, tmp_path, little_memory, call
):
    import claravid.eval as ev

    reps, tmp = label_map_reports, label_map_reports["tmp"]
    huge = ev.Bootstrap(resamples=int(HUGE))
    data = ev.DataChoice(root=reps["root"], split="all", palette="uavid")
    report = ev.ReportSettings(bootstrap=huge)
    with pytest.raises(ValueError, match=r"resamples .* GiB .* lower --bootstrap"):
        if call == "evaluate":
            ev.evaluate(tmp_path / "o", predictions=tmp / "pred_a", data=data, report=report)
        elif call == "merge":
            ev.merge([tmp / "a"], tmp_path / "o", report)
        elif call == "compare":
            ev.compare([tmp / "a", tmp / "b"], tmp_path / "o", huge)
        elif call == "score_metrics":
            csv = _scores_csv(reps, tmp_path)
            ev.score_metrics(csv, tmp_path / "o", data=ev.DataChoice(root=reps["root"]),
                             report=report)  # fmt: skip
        else:
            result = ev.load_result(tmp / "a")
            ev.build_report(result, bootstrap=ev.Bootstrap(resamples=int(HUGE), cluster="block"))
    assert not (tmp_path / "o").exists()
