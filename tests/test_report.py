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
    for block in ("steady_state", "timing", "mpc", "wbc"):
        assert f"<h3>{block}</h3>" in page
    assert "vx_rms_error" in page and "stayed up" in page
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
        assert 'href="../index.html"' in variant_page and "<h2>Metrics</h2>" in variant_page


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
