"""Remote paths. An ``s3://`` round trip against a real S3 API, moto's server on a free loopback port
(read the sample split from the bucket, write clips and manifests back): the clips must be the local
run's bytes. A scheme whose filesystem is missing stops the run with a one-line hint (exit 2)."""

import importlib.util
import os

import boto3
import pytest
from apache_beam.io.filesystems import FileSystems
from apache_beam.options.pipeline_options import PipelineOptions
from moto.server import ThreadedMotoServer

from pipeline.io import storage
from tests.support.cli import clip_bytes, run_in_process, run_pipeline
from tests.support.s3 import explicit_options_only

BUCKET = "tapvid3d"
CREDENTIALS = {"aws_access_key_id": "testing", "aws_secret_access_key": "testing", "region_name": "us-east-1"}


@pytest.fixture(scope="module")
def s3(sample_split):
    """(endpoint URL, boto3 client) of an S3 server on 127.0.0.1 whose bucket holds the sample split
    under ``split/``; the server stops with the module. Only explicit options configure S3 here and in
    the runs: no profile, endpoint, proxy or instance metadata from the environment."""
    server = ThreadedMotoServer(ip_address="127.0.0.1", port=0, verbose=False)
    with pytest.MonkeyPatch.context() as env:
        explicit_options_only(env)
        server.start()
        try:
            host, port = server.get_host_and_port()
            endpoint = f"http://{host}:{port}"
            client = boto3.client("s3", endpoint_url=endpoint, **CREDENTIALS)
            client.create_bucket(Bucket=BUCKET)
            folder = sample_split[0]
            for parent, _, names in os.walk(folder):
                for name in names:
                    path = os.path.join(parent, name)
                    key = "split/" + os.path.relpath(path, folder).replace(os.sep, "/")
                    client.upload_file(path, BUCKET, key)
            yield endpoint, client
        finally:
            server.stop()


def s3_options(endpoint: str) -> list[str]:
    return [
        f"--s3_endpoint_url={endpoint}",
        "--s3_access_key_id=testing",
        "--s3_secret_access_key=testing",
        "--s3_region_name=us-east-1",
    ]


def objects(client, prefix: str) -> dict[str, bytes]:
    pages = client.get_paginator("list_objects_v2").paginate(Bucket=BUCKET, Prefix=prefix)
    keys = [item["Key"] for page in pages for item in page.get("Contents", [])]
    return {key[len(prefix) :]: client.get_object(Bucket=BUCKET, Key=key)["Body"].read() for key in keys}


def test_s3_round_trip_writes_the_local_runs_bytes(s3, reference_run):
    endpoint, client = s3
    split, out = f"s3://{BUCKET}/split", f"s3://{BUCKET}/out"
    # One camera (3 of the sample's 4 clips) keeps the round trip short: every unit reads the segment.
    camera = ("--set", "drivetrack.cameras=1")
    result = run_pipeline("drivetrack", "--input", split, "--output", out, *camera, *s3_options(endpoint))
    assert result.returncode == 0, result.stderr[-3000:]
    written = objects(client, "out/")
    reference = reference_run("drivetrack")
    clips = {name.split("/", 1)[1]: data for name, data in written.items() if name.startswith("drivetrack/")}
    expected = {name: data for name, data in clip_bytes(reference, "drivetrack").items() if "_000_1_" in name}
    assert len(clips) == 3
    assert clips == expected
    assert written["manifests/minival.txt"].decode().split() == [
        f"drivetrack/{name}" for name in sorted(expected)
    ]
    assert written["manifests/full_test.txt"] == b""
    assert written["failures_drivetrack.jsonl"] == b""
    assert b'"clips_written": 3' in written["run_drivetrack.json"]
    assert not [name for name in written if ".partial" in name or ".write_probe" in name]


def test_s3_calls_share_one_boto3_client_and_reads_keep_their_place(s3, sample_split, monkeypatch):
    """Beam builds a boto3 client for every S3 call; after use_options, one per process and options.
    Two files read in turns from that one client still give each file's own bytes."""
    endpoint, client = s3
    made = []
    make_client = boto3.session.Session.client
    monkeypatch.setattr(
        boto3.session.Session, "client", lambda self, *a, **k: made.append(k) or make_client(self, *a, **k)
    )
    storage.use_options(PipelineOptions(s3_options(endpoint)))
    keys = sorted(item["Key"] for item in client.list_objects_v2(Bucket=BUCKET, Prefix="split/")["Contents"])
    names = [key for key in keys if key.endswith(".parquet")][:2]
    assert len(names) == 2
    assert all(FileSystems.exists(f"s3://{BUCKET}/{key}") for key in names)
    local = [open(os.path.join(sample_split[0], key[len("split/") :]), "rb").read() for key in names]
    files = [FileSystems.open(f"s3://{BUCKET}/{key}") for key in names]
    read = [b"", b""]
    while any(len(data) < len(whole) for data, whole in zip(read, local, strict=True)):
        for i, handle in enumerate(files):
            read[i] += handle.read(4096)
    assert read == local
    assert len(made) == 1
    assert made[0]["endpoint_url"] == endpoint


@pytest.mark.parametrize("scheme", ["gs", "s3"])
def test_a_missing_extra_is_named(scheme, monkeypatch):
    """As without the extra: Beam has no GCS filesystem (ValueError), or its S3 one has no boto3."""
    get_filesystem, find_spec = FileSystems.get_filesystem, importlib.util.find_spec

    def no_gcs(path):
        if path.startswith("gs://"):
            raise ValueError("Unable to get filesystem from specified path")
        return get_filesystem(path)

    monkeypatch.setattr(FileSystems, "get_filesystem", staticmethod(no_gcs))
    monkeypatch.setattr(importlib.util, "find_spec", lambda n: None if n == "boto3" else find_spec(n))
    with pytest.raises(storage.StorageError) as caught:
        storage.check_scheme(f"{scheme}://bucket/split")
    extra = {"gs": "gcp", "s3": "aws"}[scheme]
    message = str(caught.value)
    assert f"{scheme}:// paths need the {extra} extra: pip install 'tapvid3d-pipeline[{extra}]'" in message
    assert "\n" not in message


def gcs_installed() -> bool:
    try:
        storage.check_scheme("gs://bucket/split")
    except storage.StorageError:
        return False
    return True


@pytest.mark.parametrize(
    "option, path, hint",
    [
        ("--output", "foo://bucket/out", "no usable filesystem for foo://bucket/out"),
        pytest.param(
            "--input",
            "gs://bucket/split",
            "gs:// paths need the gcp extra",
            marks=pytest.mark.skipif(gcs_installed(), reason="the gcp extra is installed"),
        ),
    ],
)
def test_cli_stops_with_a_one_line_hint(option, path, hint, tmp_path):
    paths = {"--input": str(tmp_path), "--output": str(tmp_path), option: path}
    result = run_in_process("drivetrack", *(arg for item in paths.items() for arg in item))
    assert result.returncode == 2, result.stderr[-3000:]
    assert "Traceback" not in result.stderr
    lines = result.stderr.splitlines()
    assert [line for line in lines if hint in line] == lines[-1:]
