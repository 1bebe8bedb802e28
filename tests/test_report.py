"""``cafe-mpc report DIR`` (issue 15): one self-contained ``index.html`` for a run or an experiment, checked
in headless Chromium (Debian's ``chromium``; skipped with the reason when it is missing): a screenshot, and
every image decoded."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from cafe_mpc.config import load_config
from cafe_mpc_lab.cli import main
from cafe_mpc_lab.experiments.run import run
from cafe_mpc_lab.experiments.sweep import run_experiment
from cafe_mpc_lab.report.html import ReportError, write_report
from cafe_mpc_lab.report.summary import summarize

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def run_folder(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("report") / "trot"
    run(load_config("trot", ["simulation.duration=0.6", "mpc.latency=fixed", "output.render=true"]), out)
    return out


@pytest.fixture(scope="module")
def experiment_folder(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("report") / "experiment"
    run_experiment(
        "trot-schedules",
        out,
        duration=0.4,
        overrides=["mpc.latency=fixed"],
        scheduler="synchronous",
        schedules="S0,S4",
    )
    return out


def _images(page: str) -> list[str]:
    return re.findall(r'<img[^>]* src="([^"]+)"', page)


@pytest.mark.slow
def test_a_run_report_holds_metrics_plots_and_video_in_one_file(run_folder):
    path = write_report(run_folder)
    assert path == run_folder / "index.html"
    page = path.read_text()
    pictures = sorted(run_folder.glob("*.png"))
    assert len(pictures) >= 8
    sources = _images(page)
    assert len(sources) == len(pictures) and all(src.startswith("data:image/png;base64,") for src in sources)
    # first the verdict and the numbers that matter in words with units, then the plots, the tables last
    assert '<div class="verdict ok">Stayed up for the whole 0.60 s</div>' in page
    order = ['<table class="summary">', "<h2>Plots</h2>", "<h2>All metrics</h2>", "<h2>Files</h2>"]
    positions = [page.index(marker) for marker in order]
    assert positions == sorted(positions), positions
    summary = page[positions[0] : positions[1]]
    assert "m/s forward from 0.5 s against the 0.5 m/s command" in summary
    assert "fixed latency of 20 ms" in summary and "Hz (its period asks for 50 Hz)" in summary
    assert "QP fallback" in summary and "velocity error" in summary
    assert "vx_rms_error" not in summary  # raw keys only in the full tables
    for block in ("steady_state", "timing", "mpc", "wbc"):
        assert f"<h3>{block}</h3>" in page
    assert "vx_rms_error" in page and "<details><summary>every value of <code>metrics.json</code>" in page
    assert "<th>update_ms_median</th>" in page and "</td><td>ms</td></tr>" in page  # units in their column
    video = next((p for p in run_folder.glob("run.*") if p.suffix in (".mp4", ".gif")), None)
    if video is not None:  # off-screen GL was available: the video is embedded too
        assert 'src="data:video/mp4;base64,' in page or 'src="data:image/gif;base64,' in page
    # self-contained: nothing fetched from elsewhere, links relative
    assert "http://" not in page and "https://" not in page and "<link" not in page
    assert 'href="log.npz"' in page and 'href="config.yaml"' in page


@pytest.mark.slow
def test_an_experiment_report_has_the_comparison_and_a_report_per_variant(experiment_folder):
    path = write_report(experiment_folder)
    page = path.read_text()
    assert "<h2>Comparison</h2>" in page and "<table>" in page and "S0 (Ts = 0 s)" in page
    assert len(_images(page)) == len(list(experiment_folder.glob("*.png"))) >= 1
    for variant in ("S0", "S4"):
        assert f'href="{variant}/index.html"' in page
        variant_page = (experiment_folder / variant / "index.html").read_text()
        assert 'href="../index.html"' in variant_page and "<h2>All metrics</h2>" in variant_page
        assert 'class="verdict' in variant_page


GAIT_METRICS = {
    "fell": False,
    "sim_time_s": 10.0,
    "wall_time_s": 12.5,
    "real_time_factor": 0.8,
    "control_ticks": 5000,
    "base_height_mean": 0.251,
    "base_height_min": 0.24,
    "base_height_max": 0.26,
    "roll_abs_max_rad": 0.02,
    "pitch_abs_max_rad": 0.05,
    "robot": "mini_cheetah",
    "controller": "vwbc",
    "planner": "cafe",
    "gait": "trot",
    "vx_mean": 0.5,
    "vx_rms_error": 0.06,
    "pitch_rms": 0.02,
    "steady_state": {
        "metrics_window_start_s": 0.5,
        "vx_mean": 0.21,
        "vx_rms_error": 0.3,
        "vy_rms_error": 0.01,
        "yaw_rate_rms_error": 0.02,
        "height_rms_error": 0.0023,
        "pitch_rms": 0.025,
    },
    "timing": {"mode": "measured", "period_s": 0.02, "fixed_latency_s": None, "compute_scale": 2.0},
    "mpc": {
        "solves": 150,
        "failures": 2,
        "update_ms_median": 23.2,
        "update_ms_p99": 40.0,
        "latency_ms_median": 2.0,
        "latency_ms_p99": 30.0,
        "prepare_ms_median": 22.6,
        "feedback_ms_median": 0.48,
        "rate_hz": 14.5,
        "pd_fallback_ticks": 457,
    },
    "wbc": {
        "controller": "vwbc",
        "torque_limit_violations": 0,
        "friction_cone_violations": 3,
        "foot_slip_max_m": 0.0298,
        "fallbacks": 1,
    },
    "estimator": {"kind": "ground_truth"},
}


def test_the_summary_says_what_matters_in_words_with_units():
    config = {"name": "trot", "gait": {"commands": [{"start": 0.0, "vx": 0.5, "vy": 0.0, "yaw_rate": 0.0}]}}
    summary = summarize(GAIT_METRICS, config)
    assert summary.ok is True and summary.kind == "gait"
    lines = summary.lines()
    assert (
        lines[0]
        == "trot: stayed up for the whole 10.00 s; worth a look: speed, MPC, low level (VWBC) (simulated in "
        "12.50 s of wall time, real-time factor 0.80)"
    )
    assert summary.worth_a_look == ["Speed", "MPC", "Low level (VWBC)"]
    topics = [item.topic for item in summary.findings]
    assert topics == ["Speed", "Height", "Attitude", "MPC", "Low level (VWBC)", "Estimator"]
    status = {item.topic: item.status for item in summary.findings}
    speed = summary.findings[0].text
    assert speed.startswith("0.210 m/s forward from 0.5 s against the 0.5 m/s command (0.290 m/s slow)")
    assert status["Speed"] == "warn"  # more than 0.1 m/s + 20 % off its command
    mpc = summary.findings[3].text
    assert "14.5 Hz (its period asks for 50 Hz): the computer did not keep up" in mpc
    assert "measured latency" in mpc and "compute times x2" in mpc and "2 failed" in mpc
    assert status["MPC"] == "warn"
    low = summary.findings[4].text
    assert "1 QP fallback " in low and "457 of 5000 ticks held off the plans by the safe ladder" in low
    assert "3 ticks outside the friction cone" in low and "29.8 mm" in low
    assert "2.3 mm" in summary.findings[1].text
    assert summary.findings[-1].text == "ground_truth: the controller saw the simulator's state"

    fell = summarize({**GAIT_METRICS, "fell": True, "fall_time_s": 1.234, "fall_reason": "tilt"}, config)
    assert fell.ok is False and fell.verdict.startswith("Fell at 1.23 s (tilt)")
    ramped = dict(config, gait={**config["gait"], "start_stance": 0.2, "command_ramp": 0.5})
    short = summarize({**GAIT_METRICS, "sim_time_s": 0.6}, ramped).findings[0]
    assert short.status == "info" and short.text.endswith(
        "too short to judge: the command ramps in until 0.70 s"
    )
    assert summarize(GAIT_METRICS, ramped).findings[0].status == "warn"  # 10 s: judged
    several = dict(config, gait={"commands": [{"start": 0.0, "vx": 0.0}, {"start": 1.0, "vx": 0.8}]})
    assert summarize(GAIT_METRICS, several).findings[0].text.startswith("follows 2 commands (0 to 0.8 m/s")


def test_the_summary_of_a_task_gives_its_criteria_and_margins():
    task = {
        "name": "running-barrel-roll",
        "success": False,
        "failed_criteria": ["bar_contact"],
        "unjudged": {},
        "roll_turned_rad": 6.3,
        "roll_target_rad": 6.283,
        "max_base_height_m": 0.53,
        "touchdown_s": 3.11,
        "planned_touchdown_s": 3.16,
        "landed": True,
        "tilt_max_first_second_after_landing_rad": 0.14,
        "stayed_up_s": 3.7,
        "bar_contact": True,
        "bar_touched_by": ["trunk"],
        "bar_first_contact_s": 2.95,
        "bar_height_m": 0.4,
        "roll_motor_torque_limit_violations": 0,
        "approach_speed_command_mps": 0.8,
        "resume_speed_command_mps": 0.8,
        "speed_before_roll_mps": 0.82,
        "speed_after_roll_mps": 0.85,
        "pace_resumed": True,
        "criteria": {"roll_turned": "integral of the body roll rate >= 6.2832 - 0.3 rad"},
    }
    metrics = {**GAIT_METRICS, "gait": None, "task": task}
    summary = summarize(metrics, {"name": "running-barrel-roll"})
    assert summary.ok is False and summary.kind == "task"
    assert summary.verdict.startswith(
        "Stayed up for the whole 10.00 s, but the running barrel roll failed: bar contact"
    )
    found = {item.topic: item for item in summary.findings}
    assert found["Roll"].status == "ok" and found["Roll"].rule.startswith("integral of the body roll rate")
    assert found["Bar"].status == "bad" and found["Bar"].text == "touched (0.40 m high) by trunk at 2.95 s"
    assert "50 ms early on the plan" in found["Flight"].text
    assert "0.85 m/s at the end (command 0.80 m/s); the pace resumed" in found["Speed"].text
    flip = {**task, "rotation_axis": "pitch", "roll_turned_rad": 0.01, "rotation_turned_rad": 6.3}
    pitch = {item.topic: item for item in summarize({**metrics, "task": flip}).findings}["Pitch"]
    assert pitch.text.startswith("6.30 rad of the 6.28 rad asked")  # a flip: about its own axis
    cleared = summarize({**metrics, "task": {**task, "bar_contact": False, "bar_clearance_min_m": 0.0325}})
    assert "cleared (0.40 m high) by 32.5 mm" in {item.topic: item for item in cleared.findings}["Bar"].text


def test_report_errors_are_one_line(tmp_path, capsys):
    with pytest.raises(ReportError, match="neither a run folder"):
        write_report(tmp_path)
    assert main(["report", str(tmp_path / "missing")]) == 2
    assert capsys.readouterr().err.strip().splitlines() == [
        f"cafe-mpc: error: {tmp_path / 'missing'} is not a folder"
    ]


def _chromium() -> str:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        found = shutil.which(name)
        if found:
            return found
    pytest.skip("no headless Chromium (Debian: apt-get install chromium)")


def _chromium_run(arguments: list[str], tmp_path: Path) -> subprocess.CompletedProcess:
    command = [
        _chromium(),
        "--headless",
        "--no-sandbox",  # as root in a container
        "--disable-gpu",
        "--hide-scrollbars",
        f"--user-data-dir={tmp_path / 'chromium-profile'}",
        "--virtual-time-budget=10000",
        *arguments,
    ]
    return subprocess.run(command, capture_output=True, text=True, timeout=120)


@pytest.mark.display
@pytest.mark.parametrize("which", ["run", "experiment"])
def test_reports_render_in_headless_chromium_with_every_image_loaded(
    which, run_folder, experiment_folder, tmp_path
):
    folder = run_folder if which == "run" else experiment_folder
    page = write_report(folder)
    url = page.resolve().as_uri()  # from the file system, as a user opens it
    shot = tmp_path / "shot.png"
    result = _chromium_run(["--window-size=1280,2400", f"--screenshot={shot}", url], tmp_path)
    assert shot.is_file(), result.stderr[-2000:]
    data = shot.read_bytes()
    assert data.startswith(PNG_SIGNATURE) and len(data) > 20000
    dom = _chromium_run(["--dump-dom", url], tmp_path).stdout
    body = re.search(r"<body[^>]*>", dom)
    assert body is not None, dom[:500]
    images = re.search(r'data-images="(\d+)"', body.group(0))
    broken = re.search(r'data-broken="(\d+)"', body.group(0))
    assert images is not None and broken is not None, body.group(0)  # the page's load check ran
    assert int(images.group(1)) == len(_images(page.read_text())) > 0
    assert int(broken.group(1)) == 0


def test_report_command_prints_where_it_wrote(run_folder):
    result = subprocess.run(
        [sys.executable, "-m", "cafe_mpc_lab.cli", "report", str(run_folder)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 0, result.stderr
    assert f"report written to {run_folder / 'index.html'}" in result.stdout
