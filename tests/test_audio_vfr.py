"""Issue 15 (2, 3): the source's audio reaches avatar.mp4 and compare.mp4, and a
variable-frame-rate clip's frames keep their presentation times (clips made here)."""

from __future__ import annotations

from fractions import Fraction

import av
import numpy as np
import pytest

from capture2face.io.video_output import VideoWriter, is_constant_rate

SR = 44100
VFR_MS = np.array([0, 33, 50, 116, 133, 233, 250, 300, 400, 416, 450, 550, 566, 600, 700, 716,
                   750, 800, 816, 900])  # frame steps of 16-100 ms, as a phone records


def tone(seconds: float, sr: int = SR) -> np.ndarray:
    return (0.3 * np.sin(2 * np.pi * 440 * np.arange(int(round(sr * seconds))) / sr)).astype(np.float32)[None]


def add_tone(container, codec: str):
    stream = container.add_stream(codec, rate=SR)
    stream.layout = "mono"
    return stream


def write_tone(container, stream, seconds: float, fmt: str = "fltp") -> None:
    x = tone(seconds)
    if fmt == "s16":
        x = (x * 32767).astype(np.int16)
    for i in range(0, x.shape[1], 1024):
        frame = av.AudioFrame.from_ndarray(np.ascontiguousarray(x[:, i:i + 1024]), format=fmt, layout="mono")
        frame.sample_rate, frame.pts, frame.time_base = SR, i, Fraction(1, SR)
        for packet in stream.encode(frame):
            container.mux(packet)
    for packet in stream.encode():
        container.mux(packet)


def remux(src, dst, pts_ms=None, audio: str | None = "aac", audio_seconds: float | None = None,
          audio_fmt: str = "fltp"):
    """``src``'s frames re-encoded into ``dst``, at ``pts_ms`` (ms) when given, plus a tone."""
    frames = []
    with av.open(str(src)) as c:
        frames = [f.to_ndarray(format="rgb24") for f in c.decode(video=0)]
    if pts_ms is not None:
        frames = frames[:len(pts_ms)]
    h, w = frames[0].shape[:2]
    tb = Fraction(1, 1000)
    with av.open(str(dst), "w") as c:
        v = c.add_stream("libx264", rate=30)
        v.width, v.height, v.pix_fmt = w, h, "yuv420p"
        if pts_ms is not None:
            v.time_base = v.codec_context.time_base = tb
        a = add_tone(c, audio) if audio else None
        for i, img in enumerate(frames):
            vf = av.VideoFrame.from_ndarray(img, format="rgb24")
            if pts_ms is not None:
                vf.pts, vf.time_base = int(pts_ms[i]), tb
            for packet in v.encode(vf):
                c.mux(packet)
        for packet in v.encode():
            c.mux(packet)
        if audio:
            seconds = audio_seconds or (len(frames) / 30 if pts_ms is None else pts_ms[-1] / 1000 + 0.05)
            write_tone(c, a, seconds, audio_fmt)
    return dst


def probe(path):
    """``{"video": [pts seconds...], "audio": seconds or None, "video_s": seconds, "n": frames}``."""
    with av.open(str(path)) as c:
        v = c.streams.video[0]
        out = {"rate": v.average_rate, "time_base": v.time_base,
               "video_s": float(v.duration * v.time_base), "audio": None}
        if c.streams.audio:
            a = c.streams.audio[0]
            out["audio"] = float(a.duration * a.time_base)
            out["audio_codec"] = a.codec_context.name
        out["pts"] = np.array([float(f.pts * f.time_base) for f in c.decode(video=0)])
        out["n"] = len(out["pts"])
    return out


@pytest.fixture(scope="module")
def face_clip(tmp_path_factory):
    from capture2face.synth import SynthOptions, synthesize

    path = tmp_path_factory.mktemp("av") / "face.mp4"
    synthesize(path, SynthOptions(frames=24, size=256, seed=3), progress=False)
    return path


@pytest.fixture(scope="module")
def vfr_run(face_clip, tmp_path_factory):
    """A VFR clip with an AAC tone, run with compare.mp4."""
    from capture2face.pipeline import RunOptions, run
    from capture2face.render import RenderOptions

    folder = tmp_path_factory.mktemp("vfr")
    clip = remux(face_clip, folder / "vfr.mp4", pts_ms=VFR_MS)
    report = run(clip, folder / "out", RunOptions(render=RenderOptions(size=64), compare=True), progress=False)
    return clip, folder / "out" / "vfr", report


def test_variable_rate_clip_keeps_its_frame_times_and_audio(vfr_run):
    clip, folder, report = vfr_run
    src = probe(clip)
    assert src["n"] == len(VFR_MS) and src["audio"] is not None
    np.testing.assert_allclose(src["pts"], VFR_MS / 1000, atol=1e-9)
    for name in ("avatar.mp4", "compare.mp4"):
        out = probe(folder / name)
        assert out["n"] == src["n"] == report["frames"]
        tick = float(Fraction(1, 1000))  # the source's time base
        assert np.abs(out["pts"] - src["pts"]).max() <= tick, name
        # the last frame lasts as long as the step before it: duration = source's span + one step
        assert out["video_s"] == pytest.approx(src["pts"][-1] + (src["pts"][-1] - src["pts"][-2]), abs=tick)
        assert out["audio_codec"] == "aac"
        assert out["audio"] == pytest.approx(src["audio"], abs=0.03), name  # one AAC frame: 23 ms
    assert not any("audio" in w for w in report["warnings"])


def test_no_audio_option_leaves_the_audio_out(vfr_run, tmp_path):
    from capture2face.pipeline import RunOptions, run
    from capture2face.render import RenderOptions

    clip, _, _ = vfr_run
    run(clip, tmp_path / "out", RunOptions(render=RenderOptions(size=64), compare=False, audio=False), progress=False)
    out = probe(tmp_path / "out" / "vfr" / "avatar.mp4")
    assert out["audio"] is None and out["n"] == len(VFR_MS)


def test_constant_rate_clip_without_audio_is_written_as_before(face_clip, tmp_path, caplog):
    from capture2face.pipeline import RunOptions, run
    from capture2face.render import RenderOptions

    report = run(face_clip, tmp_path / "out", RunOptions(render=RenderOptions(size=64), compare=False), progress=False)
    src, out = probe(face_clip), probe(tmp_path / "out" / "face" / "avatar.mp4")
    assert out["audio"] is None
    assert (out["n"], out["rate"]) == (src["n"], src["rate"]) == (24, 30)
    np.testing.assert_allclose(out["pts"], np.arange(24) / 30, atol=1e-4)
    assert out["time_base"] != Fraction(1, 90000)  # the constant-rate path, B-frames and all
    assert not [w for w in report["warnings"] if "audio" in w]
    assert not [r for r in caplog.records if r.levelname == "WARNING"]


def test_cli_no_audio_reaches_the_options(monkeypatch, tmp_path):
    import capture2face.batch
    import capture2face.pipeline
    from capture2face import cli

    seen = []

    class Seen(Exception):
        pass

    def fake_run(clip, out, options, *args, **kw):  # stops the command once it has its options
        seen.append(options.audio)
        raise Seen

    fake_batch = fake_run

    monkeypatch.setattr(capture2face.pipeline, "run", fake_run)
    monkeypatch.setattr(capture2face.batch, "run_batch", fake_batch)
    clip = tmp_path / "c.mp4"
    clip.write_bytes(b"x")
    for argv in (["run", str(clip), "-o", str(tmp_path / "o")],
                 ["run", str(clip), "-o", str(tmp_path / "o"), "--no-audio"],
                 ["batch", str(clip), "-o", str(tmp_path / "o")],
                 ["batch", str(clip), "-o", str(tmp_path / "o"), "--no-audio"]):
        args = cli.build_parser().parse_args(argv)
        with pytest.raises(Seen):
            args.func(args)
    assert seen == [True, False, True, False]


# ---- the writer alone (no tracking) ------------------------------------------------------
def noise(n, h=48, w=64):
    rng = np.random.default_rng(0)
    return [rng.integers(0, 256, (h, w, 3), dtype=np.uint8) for _ in range(n)]


def source_with(path, codec, fmt="fltp", seconds=1.0):
    with av.open(str(path), "w") as c:
        v = c.add_stream("libx264", rate=30)
        v.width, v.height, v.pix_fmt = 64, 48, "yuv420p"
        a = add_tone(c, codec)
        for img in noise(30):
            for packet in v.encode(av.VideoFrame.from_ndarray(img, format="rgb24")):
                c.mux(packet)
        for packet in v.encode():
            c.mux(packet)
        write_tone(c, a, seconds, fmt)
    return path


@pytest.mark.parametrize("codec, fmt, ext, copied", [("aac", "fltp", ".mp4", "aac"),
                                                      ("libmp3lame", "fltp", ".mp4", "mp3"),
                                                      ("pcm_s16le", "s16", ".mov", None)])
def test_writer_copies_or_reencodes_audio(tmp_path, codec, fmt, ext, copied):
    src = source_with(tmp_path / f"src{ext}", codec, fmt)
    with av.open(str(src)) as c:
        src_packets = [(p.pts, bytes(p)) for p in c.demux(audio=0) if p.size]
    out_path = tmp_path / "out.mp4"
    with VideoWriter(out_path, 30, (64, 48), audio_from=src) as out:
        for img in noise(30):
            out.write(img)
    assert out.has_audio
    out_info = probe(out_path)
    assert out_info["audio"] == pytest.approx(1.0, abs=0.03)
    with av.open(str(out_path)) as c:
        name = c.streams.audio[0].codec_context.codec.canonical_name
        out_packets = [(p.pts, bytes(p)) for p in c.demux(audio=0) if p.size]
    assert name == (copied or "aac")
    if copied:  # stream copy: the packets themselves (priming included), up to the video's end
        assert len(src_packets) - 1 <= len(out_packets) <= len(src_packets)
        assert out_packets == src_packets[:len(out_packets)]


def test_audio_longer_than_the_video_is_cut_at_its_end(tmp_path):
    src = source_with(tmp_path / "long.mp4", "aac", seconds=3.0)
    with VideoWriter(tmp_path / "out.mp4", 30, (64, 48), audio_from=src) as out:
        for img in noise(15):
            out.write(img)
    assert probe(tmp_path / "out.mp4")["audio"] == pytest.approx(0.5, abs=0.03)


def test_constant_rate_detection():
    assert is_constant_rate(np.arange(100) / 30.0, 30)
    assert is_constant_rate(np.round(np.arange(100) / 30.0, 3), 30)  # ms time base rounding
    assert is_constant_rate(np.arange(100) * 1001 / 30000, Fraction(30000, 1001))
    assert not is_constant_rate(VFR_MS / 1000, 17.3)
    assert not is_constant_rate(np.arange(100) / 29.0, 30)  # drifts a frame over the clip
