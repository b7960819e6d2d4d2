"""``--plots DIR`` of ``imudiag diagnose``, ``calibrate`` and ``model-check``: real commands
on the shipped Xsens MTi recording (tests/data/real/xsens-mti-multiposition, SOURCE.md
there) with its --like certificate; real PNG files written by matplotlib. ``diagnose`` and
``calibrate`` with figures run as real subprocesses (the module's fixtures; ``model-check``'s
in tests/test_modelcheck.py), the other cases by the command's entry point in this process
(``conftest.run_imudiag_in_process``)."""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
import pytest
from conftest import (
    DATA_DIR,
    REAL_DATA_DIR,
    run_imudiag,
    run_imudiag_in_process,
    run_imudiag_without,
)

from imudiag.monitor import F0Trace

pytest.importorskip("matplotlib")  # the test extra installs it (extra plots)

LOG = REAL_DATA_DIR / "xsens-mti-multiposition" / "session.csv.gz"
LIKE = DATA_DIR / "diagnosis" / "like-xsens.yaml"
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def png_size(path: Path) -> tuple[int, int]:
    """(width, height) in pixels of a PNG file, from its IHDR chunk; fails if not a PNG."""
    head = path.read_bytes()[:24]
    assert head[:8] == PNG_MAGIC, f"{path}: not a PNG file"
    assert head[12:16] == b"IHDR", f"{path}: no IHDR chunk first"
    return struct.unpack(">II", head[16:24])


def check_figures(paths: list[str], names: tuple[str, ...], directory: Path) -> None:
    assert [Path(p).name for p in paths] == list(names)
    for p in paths:
        f = Path(p)
        assert f.parent.resolve() == directory.resolve()
        assert f.stat().st_size > 20_000  # a drawn figure, not an empty canvas
        w, h = png_size(f)
        assert 800 <= w <= 2000 and 500 <= h <= 1400, (f, w, h)
    assert not list(directory.glob("*.part")) and not list(directory.glob(".*"))


@pytest.fixture(scope="module")
def diagnosed(tmp_path_factory):
    d = tmp_path_factory.mktemp("diagnose")
    plots = d / "figures" / "diagnose"  # two levels that do not exist yet
    res = run_imudiag(
        "diagnose", str(LOG), "--certificate", str(LIKE), "--plots", str(plots),
        "--json", str(d / "report.json"),
    )  # fmt: skip
    assert res.returncode == 0, res.stderr
    return res, json.loads((d / "report.json").read_text()), plots


def test_diagnose_writes_the_three_figures_and_lists_them(diagnosed):
    res, report, plots = diagnosed
    names = ("estimates_accel.png", "estimates_gyro.png", "f0_trace.png")
    check_figures(report["plots"], names, plots)
    for p in report["plots"]:
        assert f"plot: {p}" in res.stdout.splitlines()
    w, h = png_size(Path(report["plots"][0]))
    assert (w, h) == (1300, 950)  # 13 x 9.5 in at 100 dpi: 9 panels a navigator can read
    # the figures do not change the diagnosis: the report is the one written without --plots
    assert report["windows_run"] == 44 and report["verdict"]["accel"] == "fault"


def test_trace_holds_every_window_and_the_f0_failures():
    """What the figures draw: every window the diagnosis ran and the failing F0 checks."""
    from imudiag.certificate import load
    from imudiag.diagnosis.config import DiagnosisConfig
    from imudiag.diagnosis.session import DiagnosisTrace, diagnose_recording

    trace = DiagnosisTrace()
    report = diagnose_recording(LOG, load(LIKE), DiagnosisConfig(), trace=trace)
    assert len(trace.windows) == report["windows_run"] == 44
    assert [w.index for w in trace.windows] == list(range(44))
    acc = trace.f0["accel"]
    failed = report["f0"]["accel"]["failed"]  # samples in failing checks
    assert acc.check == "f0" and acc.limit == pytest.approx(0.01)
    assert 0 < acc.failed.seen <= failed and failed % acc.failed.seen == 0
    t, v = acc.failed.arrays()
    assert np.all(np.abs(v) > acc.limit) and np.all(np.diff(t) >= 0)
    t, v = acc.passed.arrays()
    assert np.all(np.abs(v) <= acc.limit)
    assert trace.f0["gyro"].check == "rest_rate" and trace.f0["gyro"].failed.seen == 0
    assert trace.t0 == pytest.approx(0.0, abs=1.0)


def test_f0_trace_is_bounded_and_keeps_every_kth():
    tr = F0Trace("f0", 0.01, max_points=1000)
    rng = np.random.default_rng(3)
    for start in range(0, 100_000, 7_000):
        t = np.arange(start, min(start + 7_000, 100_000), dtype=float)
        v = rng.normal(0.0, 0.004, t.size)
        tr.add(t, v, np.abs(v) > 0.01)
    assert tr.checks == 100_000
    for part in (tr.passed, tr.failed):
        t, v = part.arrays()
        assert 0 < t.size <= 1000 and part.stride & (part.stride - 1) == 0
        assert np.all(np.diff(t) > 0)
    assert tr.failed.seen == pytest.approx(100_000 * 0.0124, rel=0.1)  # 2.5 sigma both tails


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    d = tmp_path_factory.mktemp("calibrate")
    res = run_imudiag(
        "calibrate", str(LOG), "--like", str(LIKE), "--out", str(d / "cal.yaml"),
        "--plots", str(d / "plots"), "--json", str(d / "summary.json"),
    )  # fmt: skip
    assert res.returncode == 0, res.stderr
    return res, json.loads((d / "summary.json").read_text()), d / "plots"


def test_calibrate_writes_residual_figures_and_lists_them(calibrated):
    res, summary, plots = calibrated
    check_figures(summary["plots"], ("accel_norm_residuals.png", "rotation_residuals.png"), plots)
    for p in summary["plots"]:
        assert f"plot: {p}" in res.stdout.splitlines()
    # the spreads the figures draw are the summary's, unchanged by the refactoring
    spread = summary["accel_norm_spread"]
    assert spread["before"]["rms"] == pytest.approx(4.045e-3, rel=1e-3)
    assert spread["after"]["rms"] == pytest.approx(1.070e-4, rel=1e-2)
    rot = summary["rotation_residual_rms_deg"]
    assert rot["before"] == pytest.approx(3.333, rel=1e-3)
    assert rot["after"] == pytest.approx(0.499, rel=1e-2)


def test_calibration_residuals_match_the_summary():
    from imudiag.certificate import load
    from imudiag.diagnosis.config import DiagnosisConfig
    from imudiag.diagnosis.session import calibrate_recording

    result = calibrate_recording(LOG, load(LIKE), DiagnosisConfig())
    acc = result.residuals["accel_norm"]
    assert acc["before"].shape == acc["after"].shape == (result.intervals,)
    assert np.sqrt(np.mean(acc["after"] ** 2)) == pytest.approx(result.accel_spread_after["rms"])
    rot = result.residuals["rotation"]
    rms = float(np.sqrt(np.mean(rot["before"] ** 2)))
    assert rms == pytest.approx(result.rotation_rms_before_deg)
    assert np.all(np.diff(rot["t"]) > 0)


@pytest.mark.parametrize(
    "command",
    [
        ("diagnose", str(LOG), "-c", str(LIKE)),
        ("calibrate", str(LOG), "--like", str(LIKE), "--out", "OUT/cal.yaml"),
        ("model-check", str(LOG), "--certificate", str(LIKE)),
    ],
    ids=["diagnose", "calibrate", "model-check"],
)
def test_plots_dir_that_is_a_file_is_exit_2_before_any_work(command, tmp_path):
    blocker = tmp_path / "a-file"
    blocker.write_text("not a directory\n")
    args = [a.replace("OUT", str(tmp_path)) for a in command]
    for plots, why in ((blocker, "not a directory"), (blocker / "sub", "is not a directory")):
        res = run_imudiag_in_process(
            *args, "--plots", str(plots), "--json", str(tmp_path / "r.json")
        )
        assert res.returncode == 2, res.stderr
        lines = res.stderr.strip().splitlines()
        assert len(lines) == 1 and str(plots) in lines[0] and why in lines[0], lines
        assert "--plots" in lines[0]
        assert not (tmp_path / "r.json").exists() and not (tmp_path / "cal.yaml").exists()


def test_plots_file_that_is_an_input_is_refused(tmp_path):
    log = tmp_path / "f0_trace.png"  # the log where a figure would go
    log.write_bytes(LOG.read_bytes())
    res = run_imudiag_in_process("diagnose", str(log), "-c", str(LIKE), "--plots", str(tmp_path))
    assert res.returncode == 2
    assert "refusing to overwrite an input" in res.stderr and str(log) in res.stderr
    assert log.read_bytes() == LOG.read_bytes()


@pytest.mark.parametrize("command", ["diagnose", "calibrate", "model-check"])
def test_missing_matplotlib_is_exit_2_with_the_pip_command(command, tmp_path):
    args = {
        "diagnose": ("diagnose", str(LOG), "-c", str(LIKE)),
        "calibrate": (
            "calibrate",
            str(LOG),
            "--like",
            str(LIKE),
            "--out",
            str(tmp_path / "c.yaml"),
        ),
        "model-check": ("model-check", str(LOG), "--certificate", str(LIKE)),
    }[command]
    out = tmp_path / "r.json"
    res = run_imudiag_without(
        "matplotlib", *args, "--plots", str(tmp_path / "p"), "--json", str(out)
    )
    assert res.returncode == 2, res.stderr
    line = res.stderr.strip()
    assert "\n" not in line and "matplotlib" in line
    assert "pip install 'imudiag[plots]'" in line
    assert not out.exists() and not (tmp_path / "p").exists()  # checked before any work


def test_model_check_lists_its_plots(tmp_path):
    """model-check shares the checks and the Agg setup, and now lists its figures too."""
    sim = tmp_path / "multiposition.csv"
    res = run_imudiag_in_process("simulate", "multiposition", "--duration", "20", "--seed", "2",
                      "--param", "n=6", "--out", str(sim))  # fmt: skip
    assert res.returncode == 0, res.stderr
    out = tmp_path / "mc.json"
    res = run_imudiag_in_process(
        "model-check", str(sim), "--certificate", "config/default-certificate.yaml",
        "--plots", str(tmp_path / "p"), "--json", str(out),
    )  # fmt: skip
    assert res.returncode == 0, res.stderr
    paths = json.loads(out.read_text())["plots"]
    assert paths and all(Path(p).parent == tmp_path / "p" for p in paths)
    for p in paths:
        png_size(Path(p))
        assert f"plot: {p}" in res.stdout


def test_known_rate_calibration_draws_the_plateau_residuals(tmp_path):
    """A turntable session (gyro only; the session writer of tests/test_known_rate.py)."""
    from test_known_rate import _session, _truth

    from imudiag.certificate import load_default

    log, like = tmp_path / "table.csv", tmp_path / "like.yaml"
    _session(log, _truth().gyro, seed=4)
    load_default().save(like)
    js = tmp_path / "cal.json"
    res = run_imudiag_in_process(
        "calibrate", str(log), "--like", str(like), "--known-rate", "33.333333rpm",
        "--out", str(tmp_path / "cal.yaml"), "--plots", str(tmp_path / "p"), "--json", str(js),
    )  # fmt: skip
    assert res.returncode == 0, res.stderr
    summary = json.loads(js.read_text())
    check_figures(summary["plots"], ("gyro_norm_residuals.png",), tmp_path / "p")
    assert summary["known_rate"]["norm_spread"]["after"]["rms"] < 1e-3


# ---------------------------------------------------------------------------
# imudiag.plots.save's rules: the layout and the log-axis labels (in this process, on Agg)

_PARAMS = ("left", "right", "bottom", "top", "wspace", "hspace")


def _figure_kinds():
    """(name, figure, layout box) of each figure kind the three commands draw, with seeded
    data: the real builders of calibrate and diagnose, the model check's shapes."""
    from imudiag.diagnosis.session import DiagnosisTrace
    from imudiag.plots import TITLE_ROOM, subplots
    from imudiag.plots.calibration import _figure as calibration_figure
    from imudiag.plots.diagnosis import _f0_figure

    rng = np.random.default_rng(7)
    res = {"before": rng.normal(0, 4e-3, 40), "after": rng.normal(0, 1e-4, 40),
           "t": np.linspace(3.0, 480.0, 40)}  # fmt: skip
    yield "calibration", calibration_figure("accel_norm", res, "like.yaml"), TITLE_ROOM
    trace = DiagnosisTrace(t0=0.0)
    for name, check, limit, scale in (("accel", "f0", 0.01, 3e-3), ("gyro", "rest_rate", 1.0, 0.4)):
        tr = F0Trace(check, limit, max_points=500)
        t = np.arange(0.0, 500.0, 0.1)
        v = np.abs(rng.normal(0, scale, t.size))
        tr.add(t, v, v > limit)
        trace.f0[name] = tr
    yield "f0 trace", _f0_figure(trace), TITLE_ROOM
    fig, axes = subplots(3, 3, figsize=(13, 9.5), sharex=True)
    for i, ax in enumerate(axes.flat):
        ax.errorbar(np.arange(10.0), rng.normal(0, 10.0 ** (i - 4), 10), yerr=10.0 ** (i - 5))
        ax.set_title(f"panel {i}", fontsize=10)
        ax.set_ylabel("B [m/s^2]", fontsize=9)
        ax.ticklabel_format(axis="y", style="sci", scilimits=(-3, 6), useOffset=False)
    fig.legend(handles=[plt_line()], loc="lower center", ncol=5, fontsize=8, frameon=False)
    fig.suptitle("estimates", fontsize=12)
    yield "3x3 estimates", fig, (0.0, 0.04, 1.0, 0.97)
    fig, ax = subplots(figsize=(6, 4), dpi=90)
    tau = np.logspace(-2, 2, 30)
    ax.loglog(tau, 0.3 / np.sqrt(tau) + 1e-3 * tau, "k.-", label="measured")
    ax.set_xlabel("tau [s]")
    ax.set_ylabel("Allan deviation [output units]")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    yield "allan", fig, (0.0, 0.0, 1.0, 1.0)
    fig, (ax, ax2) = subplots(2, 1, figsize=(6, 6), sharex=True,
                              gridspec_kw={"height_ratios": [3, 1]}, dpi=90)  # fmt: skip
    ax.loglog(tau, 2e-3 / np.sqrt(tau))
    ax2.semilogx(tau, 1 + rng.normal(0, 0.1, tau.size))
    ax.set_title("noise model")
    ax2.set_xlabel("tau [s]")
    yield "noise model", fig, (0.0, 0.0, 1.0, 1.0)
    fig, axes = subplots(1, 2, figsize=(10, 4), dpi=90)
    axes[0].plot(np.arange(300.0), rng.normal(0, 0.02, 300), "k.", ms=2)
    twin = axes[1].twinx()  # two axes in one cell: measured as one, as matplotlib does
    twin.plot(np.arange(300.0), rng.normal(0, 5e4, 300))
    twin.set_ylabel("a long right-hand label [units]")
    yield "1x2 with a twin", fig, (0.0, 0.0, 1.0, 0.9)


def plt_line():
    from imudiag.plots import pyplot

    return pyplot().Line2D([], [], color="k", label="certificate")


def test_layout_gives_tight_layouts_subplot_parameters():
    """imudiag.plots.layout measures each axes once; matplotlib's tight_layout with a box
    measures the same figure twice: the parameters must be the same numbers."""
    from imudiag.plots import layout, pyplot

    for name, fig, rect in _figure_kinds():
        start = {k: getattr(fig.subplotpars, k) for k in _PARAMS}
        layout(fig, rect)
        ours = {k: getattr(fig.subplotpars, k) for k in _PARAMS}
        assert ours != start, name  # it laid the figure out
        fig.subplots_adjust(**start)
        fig.tight_layout(rect=rect)
        ref = {k: getattr(fig.subplotpars, k) for k in _PARAMS}
        assert ours == pytest.approx(ref, abs=1e-12), name
        # nothing clipped: every axes with its decorations inside the figure
        renderer = fig.canvas.get_renderer()
        for ax in fig.axes:
            box = ax.get_tightbbox(renderer)
            assert box.x0 >= 0 and box.y0 >= 0, name
            assert box.x1 <= fig.bbox.width and box.y1 <= fig.bbox.height, name
        pyplot().close(fig)


def test_log_axis_labels_are_matplotlibs_in_plain_text():
    from matplotlib import ticker

    from imudiag.plots import plain_log_label, plain_log_labels, pyplot, subplots

    assert plain_log_label(r"$\mathdefault{10^{-3}}$") == "10⁻³"
    assert plain_log_label(r"$\mathdefault{2\times10^{4}}$") == "2×10⁴"
    assert plain_log_label(r"$\mathdefault{-10^{12}}$") == "−10¹²"
    for other in ("", "0.5", r"$\mathdefault{10^{-0.50}}$", r"$x^2$"):
        assert plain_log_label(other) == other  # not a label it knows: left as it is
    labels = {}
    for plain in (False, True):
        # a wide span (decades labelled) and a narrow one (minor ticks labelled too)
        fig, (wide, narrow) = subplots(1, 2, figsize=(8, 3))
        wide.loglog([1e-3, 1e2], [1e-6, 1e1])
        narrow.semilogy([0, 1], [2e-3, 9e-3])
        if plain:
            plain_log_labels(fig)
        fig.canvas.draw()
        labels[plain] = [
            [t.get_text() for t in getter()]
            for ax in (wide, narrow)
            for getter in (
                ax.xaxis.get_ticklabels,
                ax.yaxis.get_ticklabels,
                lambda ax=ax: ax.yaxis.get_ticklabels(minor=True),
            )  # fmt: skip
        ]
        if plain:
            assert not isinstance(wide.xaxis.get_major_formatter(), ticker.LogFormatter)
        pyplot().close(fig)
    assert labels[True] == [[plain_log_label(s) for s in row] for row in labels[False]]
    flat = [s for row in labels[True] for s in row]
    assert "10⁻³" in flat and any("×10⁻³" in s for s in flat)  # minor labels kept
    assert not any("$" in s for s in flat)
