"""The episodes table: from JSON end records (the fast parse and the record-by-record one), and
from episode blocks with and without their optional columns."""

from __future__ import annotations

import json
import warnings
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pyarrow as pa
import pytest

from episode_audit import (
    CorruptEvidenceError,
    RecordEvidence,
    RecordParallelEvidence,
    open_evidence,
)
from episode_audit.format import names as fmt
from episode_audit.read import episodes
from tests.read.helpers import mcap_messages, rewrite


def _reference_episodes(records: list[bytes]) -> pa.Table:
    """The episodes table of a finished file, row by row, as the reader always built it."""
    ended: dict[int, dict[str, Any]] = {}
    for data in records:
        record = json.loads(data)
        ended[record["episode"]] = record

    def number(v: Any) -> float | None:
        return None if v is None else float(v)

    def text(v: Any) -> str | None:
        return None if v is None else json.dumps(v, separators=(",", ":"))

    rows = []
    for index in sorted(ended):
        rec = ended[index]
        error = rec.get("error") or {}
        rows.append(
            {
                "episode": index,
                "env_index": rec.get("env_index", 0),
                "agent": rec.get("agent"),
                "seed": rec.get("seed"),
                "rng_state": text(rec.get("rng_state")),
                "options": text(rec.get("options")),
                "outcome": rec["outcome"],
                "failure_label": rec.get("failure_label"),
                "truncation_reason": rec.get("truncation_reason"),
                "terminated": bool(rec.get("terminated", False)),
                "truncated": bool(rec.get("truncated", False)),
                "length": int(rec["length"]),
                "return": number(rec.get("return")),
                "term_totals": [
                    (str(k), number(v)) for k, v in (rec.get("term_totals") or {}).items()
                ],
                "start_time_ns": rec.get("start_time_ns"),
                "end_time_ns": rec.get("end_time_ns"),
                "error_type": error.get("type"),
                "error_message": error.get("message"),
                "error_during": error.get("during"),
                "notes": rec.get("notes", 0),
                "ended": True,
            }
        )
    return pa.Table.from_pylist(rows, schema=episodes.EPISODE_SCHEMA)


def _odd_records(count: int) -> list[bytes]:
    """Episode records the fast path must hand over to the record-by-record one, and others."""
    sentinel = episodes._SPLIT_VALUE
    records = []
    for i in range(count):
        record: dict[str, Any] = {
            "episode": i,
            "env_index": 0,
            "seed": None if i % 2 else i,
            "outcome": ["success", "failure", "truncated", "incomplete", "error"][i % 5],
            "terminated": i % 3 == 0,
            "truncated": i % 4 == 0,
            "length": i,
            "return": [1.5, "nan", "-inf", 2, None][i % 5],
            "term_totals": {} if i % 2 else {"a": 0.25, "b": "nan", "c": None},
            "start_time_ns": 10 * i,
            "end_time_ns": 10 * i + 5,
            "error": {"type": "ValueError", "message": 'bad "x"\n', "during": "step"}
            if i % 5 == 4
            else None,
            "notes": i % 2,
            "rng_state": {"state": {"state": 2**127 + i, "inc": 3}, "f": [0.1, 1e300]}
            if i % 3
            else None,
        }
        if i % 7 == 0:
            record["options"] = {"x": [1, sentinel, 2], "y": "é"}  # sentinel, non-ASCII
        if i % 11 == 0:
            del record["env_index"], record["notes"]
        data = json.dumps(record, separators=(",", ":")).encode()
        if i == 40:
            data = b" " + data + b"\n"  # whitespace json.loads accepts
        if i == 49:
            data = json.dumps(record, ensure_ascii=False).encode()  # UTF-8, spaces
        records.append(data)
    # a duplicate (the later one wins), out of order
    records.insert(30, records[60].replace(b'"length":60', b'"length":61'))
    records.append(records[5].replace(b'"length":5', b'"length":6'))
    return records


def test_episode_records_match_the_row_by_row_reading(
    recorded: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    ev = open_evidence(recorded)
    # the Arrow episode blocks and the JSON end records of the same file agree
    records = [d for t, _, d in mcap_messages(recorded) if t == fmt.TOPIC_EPISODE_END]
    assert ev.episodes().equals(_reference_episodes(records))
    odd = _odd_records(300)
    path = rewrite(recorded, tmp_path / "odd.mcap", end_records=odd)
    one_by_one: list[bytes] = []
    original = episodes._episode_record

    def counting(data: bytes, path: Path) -> Any:
        one_by_one.append(data)
        return original(data, path)

    monkeypatch.setattr(episodes, "_episode_record", counting)
    table = open_evidence(path).episodes()
    assert 0 < len(one_by_one) < len(odd)  # the groups with odd records only
    assert repr(table.to_pylist()) == repr(_reference_episodes(odd).to_pylist())
    lengths = table.column("length").to_pylist()
    assert (lengths[5], lengths[60]) == (6, 60)  # the later of two records of an episode wins


@pytest.mark.parametrize(
    ("record", "message"),
    [
        (b'{"episode":1,"outcome":"success"', "episode record is not valid JSON"),
        (b'{"episode":1,"outcome":"success","length":1}{}', "episode record is not valid JSON"),
        (b'[{"episode":1}]', "episode record is not a JSON object"),
        (b'{"episode":true,"outcome":"success","length":1}', "lacks 'episode' of type int"),
        (b'{"episode":1,"outcome":"success"}', "lacks 'length' of type int"),
        (b'{"episode":1,"outcome":"won","length":1}', "unknown outcome 'won'"),
        (b'{"episode":1,"outcome":"success","length":1,"seed":"s"}', "have wrong types"),
        (b'{"episode":1,"outcome":"success","length":1,"return":"x"}', "have wrong types"),
        (b'{"episode":1,"outcome":"success","length":1,"error":[1]}', "have wrong types"),
        (b'{"episode":1,"outcome":"success","length":1,"x":"' + b"y" * (1 << 20) + b'"}', "1 MiB"),
    ],
)
def test_bad_episode_records_are_corruption(
    recorded: Path, tmp_path: Path, record: bytes, message: str
) -> None:
    good = [d for t, _, d in mcap_messages(recorded) if t == fmt.TOPIC_EPISODE_END]
    record = record.replace(b'"episode":1,', b'"episode":99,')
    path = rewrite(recorded, tmp_path / "bad.mcap", end_records=[*good, record, *good])
    with pytest.raises(CorruptEvidenceError, match=rf"bad\.mcap: .*{message}"):
        open_evidence(path).episodes()


def test_a_replaced_record_with_wrong_types_is_no_error(recorded: Path, tmp_path: Path) -> None:
    good = [d for t, _, d in mcap_messages(recorded) if t == fmt.TOPIC_EPISODE_END]
    bad = b'{"episode":0,"outcome":"success","length":1,"return":"x","error":[1]}'
    path = rewrite(recorded, tmp_path / "replaced.mcap", end_records=[bad, *good])
    assert open_evidence(path).episodes().equals(open_evidence(recorded).episodes())


def test_json_column_splits_one_encoding_and_falls_back() -> None:
    values = [None, {"a": [1, 2.5]}, "s", None, [1, episodes._SPLIT_VALUE, 2], 3]
    assert episodes._json_column(values) == [
        None if v is None else json.dumps(v, separators=(",", ":")) for v in values
    ]
    assert episodes._json_column([None, None]) == [None, None]
    assert episodes._json_column([{"x": 1}]) == ['{"x":1}']


def test_episode_blocks_with_and_without_typed_options_read_as_one_table(tmp_path: Path) -> None:
    """A flush's episode block has ``options_typed`` only when one of its episodes needs it
    (a games file's block ``game`` too): the table has both columns, null where a block had
    none."""
    with warnings.catch_warnings():  # PettingZoo 1.27 deprecates the env modules (for make())
        warnings.simplefilter("ignore", DeprecationWarning)
        from pettingzoo.classic import rps_v2

    single, game = tmp_path / "single.mcap", tmp_path / "game.mcap"
    passed = [None, {"at": (1, 2)}, {"at": [1, 2]}, {"at": np.arange(2, dtype=np.uint8)}]
    with RecordEvidence(gym.make("CartPole-v1"), single) as env:
        for seed, options in enumerate(passed):
            env.reset(seed=seed, options=options)
            env.step(0)
            env.flush()  # (each episode's block on its own)
    with RecordParallelEvidence(rps_v2.parallel_env(max_cycles=1), game) as penv:
        for seed, options in enumerate(passed[:2]):
            penv.reset(seed=seed, options=options)
            penv.step(dict.fromkeys(penv.agents, 1))
            penv.flush()
    typed = [None, '{"at":{"$tuple":[1,2]}}', None]
    typed.append('{"at":{"$array":{"dtype":"|u1","shape":[2],"data":"AAE="}}}')
    ev = open_evidence(single)
    assert ev.episodes().column(fmt.COL_OPTIONS_TYPED).to_pylist() == typed
    assert ev.resets().column(fmt.COL_OPTIONS_TYPED).to_pylist() == typed
    rows = open_evidence(game).episodes().select(["game", fmt.COL_OPTIONS_TYPED]).to_pylist()
    assert sorted((r["game"], r[fmt.COL_OPTIONS_TYPED]) for r in rows) == (
        [(0, None)] * 2 + [(1, typed[1])] * 2
    )


def test_an_episode_a_torn_file_cut_off_has_its_reset_rows_typed_options(tmp_path: Path) -> None:
    path, torn = tmp_path / "whole.mcap", tmp_path / "torn.mcap"
    with RecordEvidence(gym.make("CartPole-v1"), path) as env:
        env.reset(seed=0, options={"at": (1, 2)})
        env.step(0)
        env.flush()
        torn.write_bytes(path.read_bytes())  # (before its episode's record)
    (row,) = open_evidence(torn).episodes().to_pylist()
    assert (row["ended"], row[fmt.COL_OPTIONS_TYPED]) == (False, '{"at":{"$tuple":[1,2]}}')
