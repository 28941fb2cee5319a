"""The Azure Kinect Matroska reader on small synthetic recordings made with PyAV in the SDK's
layout (rawvideo tracks titled DEPTH / IR, 16-bit big-endian grey, VFW FOURCC ``b16g``), so the
error paths the real file cannot show are exercised: unmatched frames, a missing IR track, an
8-bit track, no PyAV."""

from __future__ import annotations

import sys

import av  # a test dependency (the test extra): without it these tests fail, they do not skip
import numpy as np
import pytest
import torch

from tof_fpn_torch import io as tio

H, W = 4, 8


def _image(i: int) -> np.ndarray:
    return np.arange(H * W, dtype=np.uint16).reshape(H, W) * 7 + 100 * i


def _mkv(path, tracks=("DEPTH", "IR"), frames=2, skip_ir=(), pix_fmt="gray16be"):
    """A k4arecorder-like file. FFmpeg's Matroska muxer writes raw video in VFW mode with
    biCompression 0; the SDK's files carry the FOURCC ``b16g`` there, patched in afterwards."""
    opts = {"allow_raw_vfw": "1", "flipped_raw_rgb": "1"}
    with av.open(str(path), "w", format="matroska", options=opts) as c:
        streams = {}
        for title in tracks:
            s = c.add_stream("rawvideo", rate=30)
            s.width, s.height, s.pix_fmt = W, H, pix_fmt
            s.metadata["title"] = title
            streams[title] = s
        for i in range(frames):
            for title, s in streams.items():
                if title == "IR" and i in skip_ir:
                    continue
                img = _image(i) if pix_fmt == "gray16be" else _image(i).astype(np.uint8)
                frame = av.VideoFrame.from_ndarray(img, format=pix_fmt)
                frame.pts = i
                for pkt in s.encode(frame):
                    c.mux(pkt)
        for s in streams.values():
            for pkt in s.encode():
                c.mux(pkt)
    if pix_fmt == "gray16be":
        data = path.read_bytes()
        header = b"\x01\x00\x10\x00\x00\x00\x00\x00"  # planes 1, 16 bit, biCompression 0
        assert data.count(header) == len(tracks)
        path.write_bytes(data.replace(header, b"\x01\x00\x10\x00b16g"))
    return path


def test_synthetic_recording_decodes_exactly(tmp_path):
    rec = tio.read_azure_kinect_mkv(_mkv(tmp_path / "a.mkv", frames=3))
    assert rec.depth.shape == rec.amplitude.shape == (3, 1, H, W)
    mm = np.stack([_image(i) for i in range(3)]).astype(np.float64)
    want = torch.from_numpy((mm / 1000).astype(np.float32)).unsqueeze(1)
    want[0, 0, 0, 0] = float("nan")  # 0 mm
    torch.testing.assert_close(rec.depth, want, rtol=0, atol=0, equal_nan=True)
    assert torch.equal(rec.amplitude[:, 0], torch.from_numpy(mm.astype(np.float32)))
    # frames at 1/30 s, stored in Matroska's default 1 ms time base
    torch.testing.assert_close(
        rec.timestamps_s, torch.tensor([0.0, 0.033, 0.067], dtype=torch.float64)
    )


def test_unmatched_frames_and_missing_tracks_raise(tmp_path):
    with pytest.raises(tio.FormatError, match=r"1 depth / IR frame\(s\) without a partner"):
        tio.read_azure_kinect_mkv(_mkv(tmp_path / "s.mkv", skip_ir=(1,)))
    with pytest.raises(tio.FormatError, match=r"no IR track \(video tracks: \['DEPTH'\]\)"):
        tio.read_azure_kinect_mkv(_mkv(tmp_path / "d.mkv", tracks=("DEPTH",)))
    with pytest.raises(tio.FormatError, match="the DEPTH track is rawvideo / gray, expected"):
        tio.read_azure_kinect_mkv(_mkv(tmp_path / "g.mkv", pix_fmt="gray"))


def test_without_pyav_the_reader_says_what_to_install(tmp_path, monkeypatch):
    path = _mkv(tmp_path / "a.mkv")
    monkeypatch.setitem(sys.modules, "av", None)  # import av -> ImportError
    with pytest.raises(ImportError, match=r"needs PyAV .*pip install av"):
        tio.read_azure_kinect_mkv(path)
