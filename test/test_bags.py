"""seaforce_ros.bags offline: the files it writes (fields as Jazzy writes them, read back by
rosbags and the mcap library), mcap files cut at every point (the reader recovers every
complete chunk and says so; bag_reindex makes them whole), sqlite3 left open, and bad input
(not a bag, a cut file, an empty file) as one clear line in the reader, bag_reindex, identify
and zwidth -- never a traceback."""
import json
import pathlib
import sqlite3
import subprocess
import struct

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader
from rosbags.rosbag2 import Reader

from helpers.processes import ROOT, executable

from seaforce_ros import bags
from seaforce_ros.bags import mcapfile
from seaforce_ros.bags.metadata import QosProfile
from seaforce_ros.bags.repair import reindex_bag
from seaforce_ros.bags.typestore import message_definition

FIELDS = ("x", "v", "f_p", "f_a", "x_e", "f_e")
STATE = bags.ACTUATOR_STATE
QOS = QosProfile(history="unknown", depth=0, reliability="reliable", durability="volatile")


def _data(n, seed=0):
    rng = np.random.default_rng(seed)
    return {k: rng.standard_normal(n) for k in FIELDS}


def _rosidl_hash(msgtype):
    pkg, _, name = msgtype.split("/")
    doc = json.loads((ROOT / "install" / pkg / "share" / pkg / "msg" / f"{name}.json")
                     .read_text())
    return next(h["hash_string"] for h in doc["type_hashes"] if h["type_name"] == msgtype)


def _write(path, n=6000, storage="mcap", split=None, chunk_size=None, sent_offset=7):
    """A bag like the recorder's: log_time = stamp + sent_offset ns (receive after send)."""
    rows, stamps = bags.serialize_states(["pinch"], {"pinch": _data(n)}, t0=1.7e9)
    w = bags.BagWriter(path, storage=storage, split_duration=split, chunk_size=chunk_size,
                       custom_data={"experiment": "chirp"})
    w.add_topic("/actuator_state", STATE, [QOS])
    for i in range(n):
        w.write("/actuator_state", int(stamps[i]) + sent_offset, rows[i].tobytes(),
                int(stamps[i]))
        if i % 50 == 49:
            w.flush(int(stamps[i]))
    return w.close(), stamps


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_written_bag_has_jazzy_fields_and_every_reader_agrees(tmp_path, storage):
    meta, stamps = _write(tmp_path / "run", storage=storage, split=1.0)
    ext = ".mcap" if storage == "mcap" else ".db3"
    doc = yaml.safe_load((tmp_path / "run" / "metadata.yaml").read_text())
    info = doc["rosbag2_bagfile_information"]
    assert info["version"] == 9
    assert info["ros_distro"] == "jazzy"
    assert info["storage_identifier"] == storage
    assert info["relative_file_paths"] == [f"run_{i}{ext}" for i in range(3)]
    assert [f["message_count"] for f in info["files"]] == [2000, 2000, 2000]
    assert info["message_count"] == 6000
    assert info["starting_time"]["nanoseconds_since_epoch"] == int(stamps[0]) + 7
    assert info["duration"]["nanoseconds"] == int(stamps[-1] - stamps[0])
    assert info["custom_data"] == {"experiment": "chirp"}
    assert info["compression_format"] == "" and info["compression_mode"] == ""
    (topic,) = info["topics_with_message_count"]
    assert topic["message_count"] == 6000
    tm = topic["topic_metadata"]
    assert tm["name"] == "/actuator_state" and tm["type"] == STATE
    assert tm["serialization_format"] == "cdr"
    assert tm["type_description_hash"] == _rosidl_hash(STATE)
    inf = {"sec": 9223372036, "nsec": 854775807}
    assert tm["offered_qos_profiles"] == [{
        "history": "unknown", "depth": 0, "reliability": "reliable", "durability": "volatile",
        "deadline": inf, "lifespan": inf, "liveliness": "automatic",
        "liveliness_lease_duration": inf, "avoid_ros_namespace_conventions": False}]
    with Reader(tmp_path / "run") as reader:           # rosbags: one bag
        assert reader.message_count == 6000
        (conn,) = reader.connections
        assert conn.digest == _rosidl_hash(STATE)
        assert sum(1 for _ in reader.messages()) == 6000
    if storage == "mcap":
        for i, name in enumerate(info["relative_file_paths"]):
            with open(tmp_path / "run" / name, "rb") as fh:
                reader = make_reader(fh, validate_crcs=True)
                assert reader.get_header().profile == "ros2"
                summary = reader.get_summary()
                (schema,) = summary.schemas.values()
                assert (schema.name, schema.encoding) == (STATE, "ros2msg")
                assert schema.data.decode() == message_definition(STATE)[1]
                (channel,) = summary.channels.values()
                assert channel.message_encoding == "cdr"
                assert channel.metadata["topic_type_hash"] == _rosidl_hash(STATE)
                assert yaml.safe_load(channel.metadata["offered_qos_profiles"]) == \
                    tm["offered_qos_profiles"]
                (record,) = list(reader.iter_metadata())
                assert record.name == "rosbag2"
                stored = yaml.safe_load(record.metadata["serialized_metadata"])
                assert stored["relative_file_paths"] == info["relative_file_paths"][:i + 1]
                for k, (_s, _c, m) in enumerate(reader.iter_messages()):
                    sec, nsec = struct.unpack_from("<iI", m.data, 4)
                    assert m.publish_time == sec * 10**9 + nsec == int(stamps[2000 * i + k])
                    assert m.log_time == m.publish_time + 7
    else:
        con = sqlite3.connect(tmp_path / "run" / "run_0.db3")
        assert con.execute("SELECT schema_version, ros_distro FROM schema").fetchall() == \
            [(4, "jazzy")]
        assert con.execute("PRAGMA journal_mode").fetchone()[0] == "delete"
        name, msgtype, fmt, qos, digest = con.execute(
            "SELECT name, type, serialization_format, offered_qos_profiles, "
            "type_description_hash FROM topics").fetchone()
        assert (name, msgtype, fmt, digest) == ("/actuator_state", STATE, "cdr",
                                                _rosidl_hash(STATE))
        assert yaml.safe_load(qos) == tm["offered_qos_profiles"]
        assert con.execute("SELECT encoding FROM message_definitions").fetchone()[0] == \
            "ros2msg"
        stored = yaml.safe_load(con.execute("SELECT metadata FROM metadata").fetchone()[0])
        assert stored["version"] == 9
        con.close()
    rec = bags.read_channel(tmp_path / "run", "pinch")
    assert len(rec) == 6000 and not rec.notes


def test_mcap_cut_anywhere_recovers_every_complete_chunk_and_reindex_repairs_it(tmp_path):
    """A file cut at any byte: the reader gets exactly the messages of the chunks complete
    before the cut (and names the file); bag_reindex gives it a summary every reader opens."""
    _write(tmp_path / "full", n=3000, chunk_size=40000)
    src = (tmp_path / "full" / "full_0.mcap").read_bytes()
    with mcapfile.McapScan(tmp_path / "full" / "full_0.mcap") as scan:
        for _ in scan.messages():
            pass
        chunks = [(c.offset + c.length, sum(c.counts.values())) for c in scan.index.chunks]
    assert len(chunks) > 10
    data_end = src.rfind(b"\x0f\x04\x00\x00\x00\x00\x00\x00\x00")   # the DataEnd record
    cuts = sorted({1000, chunks[0][0] - 1, chunks[0][0], chunks[0][0] + 5, chunks[3][0] + 100,
                   chunks[-1][0] + 1, data_end, data_end + 20, len(src) - 1})
    for cut in cuts:
        d = tmp_path / f"cut{cut}"
        d.mkdir()
        (d / "cut_0.mcap").write_bytes(src[:cut])
        expected = sum(n for end, n in chunks if end <= cut)
        if expected == 0:
            with pytest.raises(bags.BagReadError, match="nothing to recover"):
                bags.read_channel(d, "pinch")
            with pytest.raises(bags.BagReadError, match="no readable file"):
                reindex_bag(d)
            continue
        rec = bags.read_channel(d, "pinch")
        assert len(rec) == expected, cut
        np.testing.assert_array_equal(rec.cycle, np.arange(expected))
        if cut < data_end:
            assert any("cut_0.mcap" in n and f"recovered {expected} messages" in n
                       for n in rec.notes), rec.notes
        report = reindex_bag(d)
        assert report.metadata.message_count == expected
        with Reader(d) as reader:
            assert sum(1 for _ in reader.messages()) == expected
        with open(d / "cut_0.mcap", "rb") as fh:
            assert sum(1 for _ in make_reader(fh, validate_crcs=True).iter_messages()) == \
                expected
        assert not bags.read_channel(d, "pinch").notes


def test_sqlite3_left_open_is_read_and_repaired(tmp_path):
    """A writer that never closed (killed): its committed batches are in the WAL."""
    rows, stamps = bags.serialize_states(["pinch"], {"pinch": _data(500)}, t0=1.7e9)
    w = bags.BagWriter(tmp_path / "b", storage="sqlite3")
    w.add_topic("/actuator_state", STATE)
    for i in range(500):
        w.write("/actuator_state", int(stamps[i]), rows[i].tobytes())
        if i in (199, 399):
            w.flush()
    # not closed: 400 committed, 100 pending -- as after a SIGKILL
    f = tmp_path / "b" / "b_0.db3"
    assert pathlib.Path(str(f) + "-wal").exists()
    rec = bags.read_channel(tmp_path / "b", "pinch")
    assert len(rec) == 400
    assert any("b_0.db3" in n and "recovered 400" in n for n in rec.notes), rec.notes
    w._open.storage.abandon()
    out = subprocess.run([str(executable("bag_reindex")), str(tmp_path / "b")],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert "b_0.db3" in out.stdout and "400 messages" in out.stdout
    with Reader(tmp_path / "b") as reader:
        assert sum(1 for _ in reader.messages()) == 400


def _cli(tool, *args):
    return subprocess.run([str(executable(tool)), *map(str, args)], capture_output=True,
                          text=True, timeout=120)


@pytest.fixture
def bad_bags(tmp_path):
    """Bag directories a user can run into: not a bag, a cut file only, an empty file only,
    and a good bag with an empty split and a cut split beside its files."""
    root = tmp_path
    (root / "notabag").mkdir()
    (root / "notabag" / "notes.txt").write_text("hello")
    _write(root / "good", n=3000, split=0.5, chunk_size=20000)
    src = (root / "good" / "good_0.mcap").read_bytes()
    (root / "cut").mkdir()
    (root / "cut" / "cut_0.mcap").write_bytes(src[:200])
    (root / "empty").mkdir()
    (root / "empty" / "empty_0.mcap").write_bytes(b"")
    (root / "good" / "good_9.mcap").write_bytes(b"")
    (root / "good" / "good_8.mcap").write_bytes(src[:300])
    (root / "garbage").mkdir()
    (root / "garbage" / "metadata.yaml").write_text("rosbag2_bagfile_information: [1, 2\n")
    return root


def test_bad_input_is_one_clear_line_everywhere(bad_bags):
    root = bad_bags
    cases = {
        root / "nothing": "no such bag",
        root / "notabag": "not a bag",
        root / "notabag" / "notes.txt": "not a bag",
        root / "cut": "nothing to recover",
        root / "empty": "empty file",
        root / "garbage": "not YAML",
    }
    for path, text in cases.items():
        with pytest.raises(bags.BagError, match=text):
            bags.read_channel(path, "pinch")
        tools = [("identify", ("--channel", "pinch", "--out", root / "p.yaml"))]
        if path.name in ("notabag", "cut"):        # zwidth reads through the same reader
            tools.append(("zwidth", ("--channel", "pinch")))
        for tool, args in tools:
            out = _cli(tool, path, *args)
            assert out.returncode == 2, (tool, path, out.stdout, out.stderr)
            errors = [line for line in out.stderr.splitlines()
                      if line.startswith(f"{tool}: error:")]
            assert "Traceback" not in out.stderr and len(errors) == 1, out.stderr
            assert text in errors[0], (tool, out.stderr)
    # bag_reindex: a directory only; one line and exit 2
    for path, text in ((root / "nothing", "no such directory"),
                       (root / "notabag", "no .mcap or .db3"),
                       (root / "notabag" / "notes.txt", "not a bag directory"),
                       (root / "cut", "no readable file"),
                       (root / "empty", "no readable file")):
        out = _cli("bag_reindex", path)
        assert out.returncode == 2 and text in out.stderr, (path, out.stderr)
        assert "Traceback" not in out.stderr and len(out.stderr.strip().splitlines()) == 1
    # a good bag with an empty and a cut file beside it: read with notes, repaired without them
    rec = bags.read_channel(root / "good", "pinch")
    assert len(rec) == 3000
    assert any("good_9.mcap" in n and "empty" in n for n in rec.notes), rec.notes
    assert any("good_8.mcap" in n and "nothing to recover" in n for n in rec.notes), rec.notes
    out = _cli("identify", root / "good", "--channel", "pinch", "--out", root / "p.yaml",
               "--quiet")
    assert "Traceback" not in out.stderr
    assert "note: " in out.stdout and "good_9.mcap" in out.stdout
    out = _cli("bag_reindex", root / "good")
    assert out.returncode == 0, out.stderr
    assert "good_9.mcap: left out: empty" in out.stdout and "good_8.mcap: left out" in out.stdout
    with Reader(root / "good") as reader:
        assert reader.message_count == 3000
