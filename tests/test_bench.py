"""Smoke test of ``tympani bench`` at tiny sizes: structure and sanity, never timing thresholds."""

from __future__ import annotations

import math
import os

import pytest

from tympani.pipeline.devtools.bench import _one_cpu, SECTIONS, BenchConfig, format_bench, loop_video, render_bench_video, run_bench
from tympani.pipeline.cli import main
from tympani.vision.frames import open_frames


@pytest.fixture(scope="module")
def tiny_video(tmp_path_factory):
    return render_bench_video(tmp_path_factory.mktemp("bench") / "tiny.mp4", n_frames=12, seed=3)


def _finite_positive(x: float) -> bool:
    return math.isfinite(x) and x > 0


def test_loop_video_repeats_the_frames(tiny_video, tmp_path):
    looped = loop_video(tiny_video, tmp_path / "long.mp4", 3)
    assert open_frames(looped).count() == 3 * open_frames(tiny_video).count()


@pytest.mark.skipif(not hasattr(os, "sched_setaffinity"), reason="no CPU affinity on this platform")
def test_one_cpu_pins_every_thread_then_restores():
    before = os.sched_getaffinity(0)
    with _one_cpu() as cpu:
        assert os.sched_getaffinity(0) == {cpu} and cpu in before
    assert os.sched_getaffinity(0) == before


def test_bench_config_checks_its_values():
    with pytest.raises(ValueError):
        BenchConfig(sections=("nope",))
    with pytest.raises(ValueError):
        BenchConfig(size=(32, 480))
    with pytest.raises(ValueError):
        BenchConfig(workers=())
    with pytest.raises(ValueError):
        BenchConfig(trials=1)  # the diagnosis needs repeats
    with pytest.raises(ValueError):
        BenchConfig(noise_sigma=-1.0)
    assert BenchConfig.quick(trials=3).trials == 3


def test_run_bench_all_sections_at_tiny_sizes(tiny_video):
    config = BenchConfig.quick(long_factor=3, trials=2, workers=(1, 2), batch_videos=2, repeats=4)
    lines: list[str] = []
    cpus = os.sched_getaffinity(0) if hasattr(os, "sched_getaffinity") else None
    result = run_bench(video=tiny_video, config=config, log=lines.append)
    assert result["errors"] == {}
    assert lines[0] == "decode vs extraction" and set(SECTIONS) <= set(lines)
    # decode vs extraction
    assert result["n_frames"] == 12 and (result["height_px"], result["width_px"]) == (480, 640)
    for key in ("decode_fps", "extract_fps", "extract_fps_cold", "ratio", "extract_vs_decode"):
        assert _finite_positive(result[key]), key
    assert result["ratio"] == pytest.approx(1.0 / result["extract_vs_decode"])
    rounds = result["extract_vs_decode_rounds"]  # one per repeat, each extraction against its own decode
    assert len(rounds) == config.repeats and all(_finite_positive(r) for r in rounds)
    # the median of the 3 warm rounds (the first round's extraction is cold)
    assert result["extract_vs_decode_median_warm"] == pytest.approx(sorted(rounds[1:])[1])
    assert result["n_ok"] >= 10
    if cpus is not None:  # timed on one CPU, and the process let go afterwards
        assert result["pinned_cpu"] in cpus and os.sched_getaffinity(0) == cpus
    groups = result["stage_groups_ms"]
    for stage in ("decode", "registration", "measure", "  edges", "  angles"):
        assert groups[stage] > 0, stage
    assert groups["measure"] >= groups["  edges"]
    # memory: each in its own process, the long video has long_factor times the frames
    mem = result["memory"]
    assert mem["short"]["n_frames"] == 12 and mem["long"]["n_frames"] == 36
    for key in ("short", "long"):
        assert 0 < mem[key]["import_rss_mib"] <= mem[key]["peak_rss_mib"] < 4096
    assert mem["growth_mib"] == pytest.approx(mem["long"]["peak_rss_mib"] - mem["short"]["peak_rss_mib"])
    # diagnosis on 5 speeds x 2 trials
    diag = result["diagnosis"]
    assert diag["speeds"] == 5 and diag["trials"] == 2 and diag["rows"] > 0 and diag["diagnose_s"] > 0
    # workers
    assert [w["workers"] for w in result["workers"]] == [1, 2]
    for w in result["workers"]:
        assert w["ok"] == w["videos"] == 2 and w["frames"] == 24 and _finite_positive(w["frames_per_s"])
    assert result["file_bytes"] == os.path.getsize(tiny_video)
    text = format_bench(result)
    assert f"{result['file_bytes'] / 12 / 1024:.1f} KiB/frame" in text
    assert f"median of the warm rounds {100.0 * result['extract_vs_decode_median_warm']:.0f} %" in text
    for fragment in ("decode only", "full extract", "% of decode speed", "per round", "registration", "edges", "angles",
                     "extraction short", "extraction long", "diagnosis", "batch workers", "bench total"):
        assert fragment in text, fragment
    assert "FAILED" not in text
    # log reading: a 50,000-row ROS force CSV, read in its own process
    logs = result["logs"]
    assert logs["rows"] == logs["samples"] == 50_000 and _finite_positive(logs["seconds"])
    assert 0 < logs["import_rss_mib"] <= logs["peak_rss_mib"] < 4096 and logs["file_mib"] > 5
    assert "log reading" in text and "50,000-row ROS force CSV" in text


def test_bench_command_skips_sections(capsys, tiny_video):
    code = main(["bench", "--video", str(tiny_video), "--quick", "--skip", "memory,diagnosis,workers,logs"])
    out, err = capsys.readouterr()
    assert code == 0 and "% of decode speed" in out and "bench total" in out
    assert "extraction short" not in out and "batch workers" not in out and "diagnosis " not in out
    assert "log reading" not in out


def test_render_bench_video_size_keeps_the_phantom(tmp_path):
    """A larger frame shows the same phantom (same scale, px/mm): the registration finds it."""
    from tympani.vision.greyscale import to_gray
    from tympani.vision.registration import register

    poses = []
    for size in ((640, 480), (960, 600)):
        video = render_bench_video(tmp_path / f"{size[0]}.mp4", n_frames=3, seed=0, size=size)
        frames = [to_gray(f.image) for f in open_frames(video)]
        assert frames[0].shape == (size[1], size[0])
        poses.append(register(frames).pose)
    assert poses[1].px_per_mm == pytest.approx(poses[0].px_per_mm, rel=0.01)


def test_render_bench_video_noise_is_a_cameras(tmp_path):
    """The default bench video carries sensor noise (2 grey levels); 0 renders it noise-free,
    otherwise the same frames. The noisy one is a bigger file: more to decode."""
    import numpy as np

    from tympani.vision.greyscale import to_gray

    clean = render_bench_video(tmp_path / "clean.mp4", n_frames=4, seed=0, noise_sigma=0.0)
    noisy = render_bench_video(tmp_path / "noisy.mp4", n_frames=4, seed=0)
    a, b = ([to_gray(f.image).astype(float) for f in open_frames(v)] for v in (clean, noisy))
    diff = np.concatenate([(y - x).ravel() for x, y in zip(a, b)])
    assert abs(diff.mean()) < 0.5 and 1.0 < diff.std() < 3.0  # the codec smooths some of the 2 levels away
    assert os.path.getsize(noisy) > 1.2 * os.path.getsize(clean)


def test_bench_command_rejects_bad_sizes(capsys):
    assert main(["bench", "--size", "1280"]) == 2
    assert "--size: '1280' is not WIDTHxHEIGHT" in capsys.readouterr().err
    assert main(["bench", "--size", "32x32"]) == 2
    assert "frames must be at least 320x240" in capsys.readouterr().err
    assert main(["bench", "--skip", "bogus"]) == 2
    assert "unknown --skip" in capsys.readouterr().err
    assert main(["bench", "--trials", "1"]) == 2
    assert "at least 2 trials" in capsys.readouterr().err
    assert main(["bench", "--noise", "-2"]) == 2
    assert "--noise: must be a number >= 0, not -2" in capsys.readouterr().err
