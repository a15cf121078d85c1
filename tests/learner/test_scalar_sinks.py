"""`--logger`: the TensorBoard backend writes event files a reader gets the scalars back from; the
W&B backend, run for real and offline (no network), writes a W&B run under the run directory
that holds a training run's metrics, keeps its id on resume and respects the user's WANDB_MODE;
choosing W&B without its package is one line naming the extra."""

from __future__ import annotations

import dataclasses
import struct
import sys
from pathlib import Path

from typing import get_args, get_type_hints

import pytest
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from learner import main as learner_main
from learner.config import RunConfig
from learner.presets import PRESETS
from learner.scalar_sinks import LOGGERS, WANDB_EXTRA, WANDB_ID_FILE, open_sink
from learner.train import train


def test_the_config_field_offers_every_backend():
    assert get_args(get_type_hints(RunConfig)["logger"]) == LOGGERS
    assert RunConfig().logger == "tensorboard"


def test_tensorboard_sink_writes_events_a_reader_gets_back(tmp_path: Path):
    sink = open_sink("tensorboard", tmp_path)
    sink.scalars({"charts/episode_return": 1.5, "losses/value": 0.25}, 1024)
    sink.scalars({"charts/episode_return": 2.5}, 2048)
    sink.close()
    acc = EventAccumulator(str(tmp_path / "tb"))
    acc.Reload()
    assert [(e.step, e.value) for e in acc.Scalars("charts/episode_return")] == [(1024, 1.5), (2048, 2.5)]
    assert [(e.step, e.value) for e in acc.Scalars("losses/value")] == [(1024, 0.25)]


def test_choosing_wandb_without_its_package_is_one_line_naming_the_extra(monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "wandb", None)  # Python's own way to make a package unimportable
    with pytest.raises(SystemExit) as exc:
        learner_main.parse(["--preset", "reach-tiny", "--logger", "wandb"])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and err.count("\n") == 1 and WANDB_EXTRA in err, err


def _wandb_records(path: Path) -> list:
    """Every record of a W&B run file (`run-<id>.wandb`): W&B's own protobuf `Record`s in the
    LevelDB log format (7-byte file header; 32 KiB blocks of chunks, each with a 7-byte header:
    checksum, length, type FULL 1 / FIRST 2 / MIDDLE 3 / LAST 4)."""
    from wandb.proto import wandb_internal_pb2  # the optional extra: the tests that read W&B runs skip without it

    data, pos, block, records, pending = path.read_bytes(), 7, 32768, [], b""
    assert data[:4] == b":W&B"
    while pos + 7 <= len(data):
        if block - pos % block < 7:  # a block's tail too short for a header is padding
            pos += block - pos % block
            continue
        _, length, kind = struct.unpack("<IHB", data[pos:pos + 7])
        if length == 0 and kind == 0:
            break
        pending += data[pos + 7:pos + 7 + length]
        pos += 7 + length
        if kind in (1, 4):
            record = wandb_internal_pb2.Record()
            record.ParseFromString(pending)
            records.append(record)
            pending = b""
    return records


def _history(run_dir: Path) -> tuple[str, list[dict[str, str]]]:
    """(the W&B run id, the logged rows) of the newest offline W&B run under `run_dir`."""
    runs = sorted((run_dir / "wandb").glob("offline-run-*"))
    assert runs, list(run_dir.iterdir())
    files = list(runs[-1].glob("run-*.wandb"))
    rows = [{"_step": str(r.history.step.num),
             **{item.key or "/".join(item.nested_key): item.value_json for item in r.history.item}}
            for r in _wandb_records(files[0]) if r.WhichOneof("record_type") == "history"]
    return files[0].stem[len("run-"):], rows


@pytest.fixture
def wandb_offline_home(tmp_path, monkeypatch):
    """W&B imported, its mode left to the backend, its settings and caches kept in tmp_path."""
    pytest.importorskip("wandb", reason="the W&B backend is an optional extra (pip install -e \".[wandb]\")")
    monkeypatch.delenv("WANDB_MODE", raising=False)
    monkeypatch.delenv("WANDB_PROJECT", raising=False)
    for var in ("WANDB_CONFIG_DIR", "WANDB_CACHE_DIR", "WANDB_DATA_DIR"):
        monkeypatch.setenv(var, str(tmp_path / "wandb-home" / var.lower()))
    return tmp_path


def test_a_training_run_logs_to_an_offline_wandb_run_and_resumes_into_the_same_one(wandb_offline_home: Path, capsys):
    cfg = dataclasses.replace(PRESETS["reach-tiny"][1], runs_dir=str(wandb_offline_home / "runs"), mode="serial",
                              logger="wandb", max_iterations=2, total_env_steps=10**6)
    assert train(cfg) == 0
    run_dir = wandb_offline_home / "runs" / "reach-tiny"
    run_id, rows = _history(run_dir)
    assert run_id == (run_dir / WANDB_ID_FILE).read_text().strip()
    assert [int(r["_step"]) for r in rows] == [1024, 2048]  # env steps
    assert all("charts/episode_return" in r and "losses/value" in r and "wire/rejected" in r for r in rows)
    assert "W&B run (offline)" in capsys.readouterr().out and not (run_dir / "tb").exists()

    assert train(dataclasses.replace(cfg, max_iterations=3)) == 0  # resumed: the same W&B run, on from its steps
    again, rows = _history(run_dir)
    assert again == run_id and [int(r["_step"]) for r in rows] == [3072]


def test_the_users_wandb_mode_is_kept(wandb_offline_home: Path, monkeypatch):
    monkeypatch.setenv("WANDB_MODE", "disabled")
    sink = open_sink("wandb", wandb_offline_home, "t", RunConfig())
    sink.scalars({"charts/episode_return": 1.0}, 1)
    sink.close()
    assert sink.mode == "disabled" and not list((wandb_offline_home / "wandb").glob("offline-run-*"))
