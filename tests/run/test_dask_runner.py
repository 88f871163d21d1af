"""The same pipeline on Beam's Dask runner, against a dask.distributed cluster of two worker
processes: its clips must be byte-identical to the DirectRunner's, and both workers must work."""

import json
import os

import pytest
from distributed import Client, LocalCluster

from tests.support.cli import clip_bytes, run_in_process


@pytest.fixture(scope="module")
def cluster():
    with (
        LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as local,
        Client(local) as client,
    ):
        yield local, client


def tasks_per_worker(client: Client) -> dict[str, int]:
    return client.run(lambda dask_worker: dask_worker.state.executed_count)


def clients_connected(client: Client) -> int:
    return client.run_on_scheduler(lambda dask_scheduler: len(dask_scheduler.clients))


@pytest.mark.parametrize("source", ["drivetrack", "pstudio"])
def test_dask_runner_writes_the_direct_runners_bytes(source, cluster, reference_run, tmp_path):
    local, client = cluster
    reference = reference_run(source)
    sample_input = json.load(open(os.path.join(reference, f"run_{source}.json")))["input"]
    before, clients = tasks_per_worker(client), clients_connected(client)
    out = str(tmp_path / "dask")
    result = run_in_process(
        source,
        "--input",
        sample_input,
        "--output",
        out,
        "--runner",
        "DaskRunner",
        f"--dask_client_address={local.scheduler_address}",
    )
    assert result.returncode == 0, result.stderr[-3000:]
    after = tasks_per_worker(client)
    # Both worker processes ran tasks of this pipeline (the submitting process runs none).
    assert set(after) == set(before)
    assert len(after) == 2
    assert all(after[worker] > before[worker] for worker in after), (before, after)
    # The run closed the client Beam's runner opened (left open, it would try to reconnect once
    # the cluster is gone).
    assert clients_connected(client) == clients
    expected = clip_bytes(reference, source)
    assert len(expected) == 4
    assert clip_bytes(out, source) == expected
    summary = json.load(open(os.path.join(out, f"run_{source}.json")))["summary"]
    assert summary == json.load(open(os.path.join(reference, f"run_{source}.json")))["summary"]


def test_a_training_run_on_dask_writes_the_direct_runners_shards(cluster, pstudio_sample, tmp_path):
    """The shards of a training run are the same files whichever runner made them (rows in the
    same order, the same shards)."""
    local, _ = cluster
    splits = tmp_path / "splits.json"
    splits.write_text(json.dumps({"minival": {}, "full_eval": {"pstudio": ["tennis_3.npz"]}}))
    runners = {
        "direct": [],
        "dask": ["--runner", "DaskRunner", f"--dask_client_address={local.scheduler_address}"],
    }
    shards = {}
    for name, extra in runners.items():
        out = tmp_path / name
        arguments = [
            "--input",
            pstudio_sample[0],
            "--output",
            str(out),
            "--training",
            "--set",
            "pstudio.cameras=3",
        ]
        result = run_in_process("pstudio", *arguments, "--set", f"training.splits_file={splits}", *extra)
        assert result.returncode == 0, result.stderr[-3000:]
        shards[name] = {
            path.name: path.read_bytes() for path in (out / "train" / "pstudio").glob("*.parquet")
        }
    assert shards["direct"] and shards["dask"] == shards["direct"]
