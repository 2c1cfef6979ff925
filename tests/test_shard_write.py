"""The fast parts of `stablemo data shard` give what the slow ones gave: the tar writer WebDataset's
bytes, the byte planes the transposed bytes, the .npy fast path np.load's arrays (and np.load's
errors where it does not apply), the one-pass finiteness check the same verdicts, the body the
per-clip median."""

from __future__ import annotations

import io
import random
import tarfile

import numpy as np
import pytest
import torch

from footskate.errors import FootskateError
from footskate.npyio import npy_from_bytes
from stablemo.data.cache import read_buffer, validate_features
from stablemo.data.layout import get_spec
from stablemo.data.shard_format import byte_planes, decode_features, encode_features
from stablemo.data.shard_tar import header, tar_bytes
from stablemo.errors import StableMoError


def test_tar_bytes_are_webdatasets_and_any_tar_reader_reads_them():
    import webdataset as wds

    rng = random.Random(0)
    for trial in range(30):
        sizes = [0, 1, 511, 512, 513, 10240, rng.randrange(200_000)]
        samples = [{"__key__": f"{k:06d}", "json": rng.randbytes(rng.randrange(600)),
                    "f32.zst": rng.randbytes(rng.choice(sizes))} for k in range(rng.randrange(12))]
        stream = io.BytesIO()
        with wds.TarWriter(stream, encoder=False, mtime=0, user="stablemo", group="stablemo", mode=0o444) as tar:
            for sample in samples:
                tar.write(sample)
        ours = tar_bytes((f"{s['__key__']}.{ext}", s[ext]) for s in samples for ext in ("f32.zst", "json"))
        assert ours == stream.getvalue(), trial
    with tarfile.open(fileobj=io.BytesIO(ours)) as tar:
        members = tar.getmembers()
        assert [m.name for m in members] == [f"{s['__key__']}.{e}" for s in samples for e in ("f32.zst", "json")]
        assert all(m.mode == 0o444 and m.mtime == 0 and m.uname == "stablemo" and m.isfile() for m in members)
        assert tar.extractfile(members[-1]).read() == samples[-1]["json"]
    assert len(tar_bytes([])) == 10240  # an empty archive: its end blocks, one record


def test_tar_header_refuses_what_ustar_cannot_hold():
    for name in ("", "x" * 101, "d\u00e9j\u00e0.json", "a\0b"):
        with pytest.raises((ValueError, UnicodeEncodeError)):
            header(name, 1)
    with pytest.raises(ValueError, match="more than a ustar header holds"):
        header("000000.json", 8**11)


def test_byte_planes_and_their_zstd_frame_round_trip():
    rng = np.random.default_rng(0)
    for shape in [(179, 263), (1, 263), (3, 7)]:
        features = (rng.standard_normal(shape) * 100).astype(np.float32)
        planes = byte_planes(features)
        assert planes.shape == (4, features.size)
        assert np.array_equal(planes, features.astype("<f4").view(np.uint8).reshape(-1, 4).T)  # plane k = byte k
        assert np.array_equal(decode_features(encode_features(features), *shape, "x"), features)
    as_f64 = rng.standard_normal((5, 263))
    assert encode_features(as_f64) == encode_features(as_f64.astype(np.float32))


def _npy(array: np.ndarray, version) -> bytes:
    stream = io.BytesIO()
    np.lib.format.write_array(stream, array, version=version)
    return stream.getvalue()


def test_npy_fast_path_gives_np_loads_arrays_and_leaves_the_rest_to_it():
    rng = np.random.default_rng(1)
    arrays = [rng.standard_normal((179, 263)).astype(np.float32), np.ones(()), np.zeros((0, 263), np.float32),
              np.arange(5, dtype=">i4"), np.arange(6, dtype=np.uint8).reshape(2, 3), np.ones(3, np.float16),
              np.asfortranarray(rng.standard_normal((3, 4))), np.ones(2, np.complex64)]
    for array in arrays:
        for version in [(1, 0), (2, 0), (3, 0)]:
            data = _npy(array, version)
            want = np.load(io.BytesIO(data))
            for given in (data, bytearray(data)):
                got = npy_from_bytes(given, "x.npy")
                assert got.dtype == want.dtype and got.shape == want.shape and np.array_equal(got, want)
                assert got.flags.writeable and got.flags.c_contiguous == want.flags.c_contiguous
    # a bytearray's array is that buffer (no copy); a bytes object's is a copy
    buffer = bytearray(_npy(np.arange(4, dtype=np.int64), (1, 0)))
    array = npy_from_bytes(buffer, "x.npy")
    array[0] = 7
    assert np.frombuffer(buffer, np.int64, 4, len(buffer) - 32)[0] == 7
    # what the fast path does not take, np.load judges, with the same messages as before
    data = _npy(np.ones((4, 4), np.float32), (1, 0))
    with pytest.raises(FootskateError, match=r"x.npy: not a readable .npy file \(EOF: reading array data"):
        npy_from_bytes(data[:-8], "x.npy")
    with pytest.raises(FootskateError, match="x.npy: expected a numeric array, found dtype bool"):
        npy_from_bytes(_npy(np.ones(3, bool), (1, 0)), "x.npy")


def test_finiteness_check_finds_nan_and_inf_where_they_are(tmp_path):
    spec = get_spec("humanml3d")
    clip = np.zeros((6, spec.feature_dim), np.float32)
    assert validate_features(clip, tmp_path / "a.npy", spec) is not None
    for bad, frame in ((np.nan, 4), (np.inf, 2), (-np.inf, 0)):
        broken = clip.copy()
        broken[frame, 9] = bad
        with pytest.raises(StableMoError, match=rf"a.npy: 1 NaN/Inf value\(s\), first in frame {frame}"):
            validate_features(broken, tmp_path / "a.npy", spec)


def test_read_buffer_reads_whole_files(tmp_path):
    for size in (0, 1, 190_000):
        path = tmp_path / f"f{size}"
        data = random.Random(size).randbytes(size)
        path.write_bytes(data)
        got = read_buffer(path)
        assert isinstance(got, bytearray) and got == data


def test_body_of_all_clips_at_once_is_the_per_clip_median():
    from stablemo.data.stats import body_lengths
    from stablemo.motion.features import features_to_joints
    from stablemo.motion.rigid import bone_lengths_of
    from stablemo.motion.skeleton import get_skeleton

    rng = np.random.default_rng(2)
    skel = get_skeleton("humanml3d")
    clips = [rng.standard_normal((n, skel.feature_dim)).astype(np.float32) * 0.3 for n in (5, 17, 9)]
    per_clip = torch.cat([bone_lengths_of(features_to_joints(torch.from_numpy(np.array(c, np.float64)), skel), skel)
                          for c in clips]).median(0).values.numpy()
    threads = torch.get_num_threads()
    got = body_lengths(clips, skel)
    assert np.array_equal(got, per_clip) and (got[1:] > 0).all()
    assert torch.get_num_threads() == threads  # its one thread is given back
