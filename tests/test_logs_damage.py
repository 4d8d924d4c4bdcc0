"""logs.reader under damage (issue 16, items 2–4 and 14): a damaged chunk costs that chunk
only, every loss is reported with what the file says was lost, and nothing is read silently
short. Chunk boundaries and per-chunk message counts come from mcap's own reader on the
intact file (an independent reader), not from ours."""

from __future__ import annotations

import warnings
from pathlib import Path

import pytest
from adfusion.logs import McapLogReader, McapSource
from adfusion.logs.reader import McapReadWarning
from test_logs import _chunks, write_full_log


@pytest.fixture
def log(tmp_path: Path) -> tuple[Path, bytes, list[tuple[int, int, int]]]:
    path = tmp_path / "full.mcap"
    write_full_log(path, n_frames=12, chunk_size=16 * 1024)
    chunks = _chunks(path)
    assert len(chunks) >= 6
    return path, path.read_bytes(), chunks


def _read(path: Path) -> tuple[McapLogReader, list, list[str]]:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        reader = McapLogReader(path)
        msgs = list(reader)
    return reader, msgs, [str(w.message) for w in caught if w.category is McapReadWarning]


def _total(chunks, skip=()) -> int:
    return sum(n for i, (_, _, n) in enumerate(chunks) if i not in skip)


def test_byte_flips_in_one_chunk_lose_that_chunk_only(log, tmp_path):
    _path, data, chunks = log
    k = 3
    bad = bytearray(data)
    for i in range(chunks[k][0] + 200, chunks[k][0] + 260):
        bad[i] ^= 0xFF
    for name, blob in (("flipped.mcap", bytes(bad)),              # complete: lazy check
                       ("flipped-cut.mcap", bytes(bad[:chunks[-1][1] - 1]))):  # full scan
        broken = tmp_path / name
        broken.write_bytes(blob)
        reader, msgs, warned = _read(broken)
        cut = name.endswith("cut.mcap")
        want = _total(chunks, skip={k, len(chunks) - 1} if cut else {k})
        assert len(msgs) == want, name
        first = reader.problems[0]
        assert first.offset == chunks[k][0] and "corrupt chunk" in first.reason
        assert first.resumed_at == chunks[k][1]
        assert any(f"broken at byte {chunks[k][0]} " in w for w in warned)
        times = [m.t_s for m in msgs]
        assert times == sorted(times)
        # messages after the damaged chunk are there
        assert max(times) > reader.problems[0].lost_t_s[1] if first.lost_t_s else True


def test_zeroed_chunk_is_reported_not_walked_as_empty_records(log, tmp_path):
    _path, data, chunks = log
    k = 2
    s, e, _n = chunks[k]
    for length in (e - s, 9 * ((e - s) // 9)):  # the whole record, and a multiple of 9
        bad = bytearray(data)
        bad[s:s + length] = bytes(length)
        broken = tmp_path / f"zero{length}.mcap"
        broken.write_bytes(bytes(bad))
        reader, msgs, warned = _read(broken)
        assert len(msgs) == _total(chunks, skip={k})
        assert reader.problems, "a zeroed chunk must be reported"
        assert reader.problems[0].offset == s
        assert warned
        # the file's own count says what was lost
        assert reader.message_count == _total(chunks, skip={k})


def test_cut_out_chunk_is_found_by_the_index_and_the_message_count(log, tmp_path):
    _path, data, chunks = log
    k = 2
    s, e, n = chunks[k]
    broken = tmp_path / "cutout.mcap"
    broken.write_bytes(data[:s] + data[e:])
    reader, msgs, warned = _read(broken)
    assert len(msgs) == _total(chunks, skip={k})
    text = " ".join(str(p) for p in reader.problems)
    assert "missing from the data section" in text
    assert f"states {_total(chunks)} messages" in text
    assert any(p.lost_messages == n for p in reader.problems)
    assert warned


def test_destroyed_chunk_header_resumes_at_the_next_indexed_chunk(log, tmp_path):
    _path, data, chunks = log
    k = 1
    s = chunks[k][0]
    bad = bytearray(data)
    bad[s + 1:s + 9] = b"\xff" * 8  # the record length: the walk cannot step over it
    broken = tmp_path / "header.mcap"
    broken.write_bytes(bytes(bad))
    reader, msgs, _ = _read(broken)
    assert len(msgs) == _total(chunks, skip={k})
    assert reader.problems[0].offset == s and reader.problems[0].resumed_at == chunks[k + 1][0]
    # without a summary (cut short) the next intact chunk is found by its CRC
    cut = tmp_path / "header-cut.mcap"
    cut.write_bytes(bytes(bad[:chunks[-1][1] - 1]))
    reader, msgs, _ = _read(cut)
    assert reader.problems[0].resumed_at == chunks[k + 1][0]
    # the lost chunk defined channels that later chunks use (no summary repeats them): those
    # messages are lost too, and said to be
    orphans = sum(p.lost_messages or 0 for p in reader.problems if "channel record" in p.reason)
    assert len(msgs) + orphans == _total(chunks, skip={k, len(chunks) - 1})


def test_changed_attachment_fails_its_crc(log, tmp_path):
    path, data, _ = log
    at = data.index(b'"fx"') if b'"fx"' in data else data.index(b'"K":[[50.0')
    bad = bytearray(data)
    i = bad.index(b"50.0", at)
    bad[i] = ord("6")  # fx 50 → 60: one digit
    broken = tmp_path / "att.mcap"
    broken.write_bytes(bytes(bad))
    reader, _, warned = _read(broken)
    assert reader.camera_model() is None
    assert any("camera.json" in w and "CRC" in w for w in warned)
    assert McapLogReader(path).camera_model() is not None


def test_not_an_mcap_file_is_said_to_be_one(tmp_path):
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"not an mcap file at all")
    with pytest.raises(ValueError, match="not an MCAP file"):
        McapSource(bad)
    short = tmp_path / "short.mcap"
    short.write_bytes(b"\x89MC")
    with pytest.warns(McapReadWarning, match="truncated"):
        assert list(McapSource(short)) == []


def test_intact_file_has_no_problem(log):
    path, _, chunks = log
    reader, msgs, warned = _read(path)
    assert reader.problems == [] and warned == []
    assert len(msgs) == _total(chunks) == reader.message_count == reader.stated_message_count


@pytest.mark.parametrize("field", ["start", "end"])
def test_damaged_chunk_header_times_keep_time_order_and_are_reported(log, tmp_path, field):
    """The chunk header's message times are outside the chunk CRC: a flipped start or end
    time once put a whole chunk's messages last (out of time order, nothing reported; found
    by `benchmarks/fuzz.py`). The chunk index disagrees and is used, and it is said."""
    _path, data, chunks = log
    bad = bytearray(data)
    at = chunks[0][0] + 9 + (4 if field == "start" else 12)  # high bytes of the u64 time
    for i in range(at, at + 4):
        bad[i] ^= 0xFF
    broken = tmp_path / "header.mcap"
    broken.write_bytes(bytes(bad))
    reader, msgs, warned = _read(broken)
    times = [m.t_s for m in msgs]
    assert times == sorted(times)
    assert len(msgs) == _total(chunks)  # the records are intact: nothing is lost
    assert any(p.offset == chunks[0][0] and "chunk index" in p.reason
               for p in reader.problems), reader.problems
    assert warned


def test_messages_outside_their_chunks_times_are_reported_not_misordered(log, tmp_path):
    """When the chunk index says the same (a writer that computes no summary CRC, so the
    damage cannot be told from the truth), a chunk whose stated times do not cover its own
    messages is reported, and nothing is delivered out of time order."""
    import struct

    _path, data, chunks = log
    bad = bytearray(data)
    times_at = chunks[1][0] + 9
    late_ns = struct.unpack_from("<Q", data, chunks[4][0] + 9 + 8)[0]  # chunk 4's end
    idx = bytes(data).rfind(data[times_at:times_at + 16])  # the same pair in the index
    assert idx > chunks[-1][1]
    for at in (times_at, idx):  # chunk 1 now claims to start after chunk 4
        struct.pack_into("<QQ", bad, at, late_ns, late_ns + 1)
    struct.pack_into("<I", bad, len(bad) - 8 - 4, 0)  # footer: summary CRC "not computed"
    broken = tmp_path / "both.mcap"
    broken.write_bytes(bytes(bad))
    reader, msgs, warned = _read(broken)
    times = [m.t_s for m in msgs]
    assert times == sorted(times)
    assert any("outside its stated times" in p.reason for p in reader.problems)
    lost = _total(chunks) - len(msgs)
    assert lost > 0 and sum(p.lost_messages or 0 for p in reader.problems) >= lost
    assert warned
