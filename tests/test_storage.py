"""Evidence in object storage: every reading command on ``s3://`` inputs, against a real server.

The server is moto's S3 server (``ThreadedMotoServer``) on a free loopback port, reached over
HTTP by s3fs through ``AWS_ENDPOINT_URL`` as any S3-compatible store is; its app is wrapped to
count the bytes it serves, so that ``report`` is shown to read a small part of a large file.
"""

from __future__ import annotations

import importlib.util
import json
import os
import pickle
import re
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pyarrow.parquet as pq
import pytest
from typer.testing import CliRunner

from episode_audit import RecordEvidence, check, export, open_evidence, replay
from episode_audit.cli import app
from episode_audit.errors import ConfigurationError, EvidenceError
from episode_audit.read import evidence_files, steps_total
from episode_audit.read.storage import RemoteFile, shown_url
from episode_audit.report import report_inputs

s3fs = pytest.importorskip("s3fs")
moto_server = pytest.importorskip("moto.moto_server.threaded_moto_server")
werkzeug_app = pytest.importorskip("moto.moto_server.werkzeug_app")
werkzeug_serving = pytest.importorskip("werkzeug.serving")

REPO = Path(__file__).resolve().parents[1]
BUCKET = "evidence"
runner = CliRunner()


class _CountingApp:
    """A WSGI app that serves what ``app`` does and counts the body bytes of GET answers."""

    def __init__(self, app: Any) -> None:
        self.app = app
        self.served = 0
        self.requests = 0
        self._lock = threading.Lock()

    def __call__(self, environ: dict[str, Any], start_response: Any) -> Iterable[bytes]:
        body = self.app(environ, start_response)
        try:
            data = b"".join(body)
        finally:
            getattr(body, "close", lambda: None)()
        if environ["REQUEST_METHOD"] == "GET":
            with self._lock:
                self.served += len(data)
                self.requests += 1
        return [data]


class CountingMotoServer(moto_server.ThreadedMotoServer):  # type: ignore[misc]
    """moto's threaded S3 server, its app wrapped in :class:`_CountingApp`."""

    def _server_entry(self) -> None:
        app = werkzeug_app.DomainDispatcherApplication(werkzeug_app.create_backend_app)
        self.counter = _CountingApp(app)
        self._server = werkzeug_serving.make_server(
            self._ip_address,
            self._port,
            self.counter,
            True,
            request_handler=werkzeug_app.MotoRequestHandler,
        )
        self._server_ready_event.set()
        self._server.serve_forever()


_ENV = {
    "AWS_ACCESS_KEY_ID": "testing",
    "AWS_SECRET_ACCESS_KEY": "testing",
    "AWS_DEFAULT_REGION": "us-east-1",
    "AWS_EC2_METADATA_DISABLED": "true",  # never ask an instance-metadata address
    "AWS_SHARED_CREDENTIALS_FILE": "/nonexistent",
    "AWS_CONFIG_FILE": "/nonexistent",
}


@pytest.fixture(scope="module")
def server() -> Iterator[CountingMotoServer]:
    srv = CountingMotoServer(ip_address="127.0.0.1", port=0, verbose=False)
    srv.start()
    try:
        yield srv
    finally:
        srv.stop()


@pytest.fixture(scope="module")
def endpoint(server: CountingMotoServer) -> str:
    host, port = server.get_host_and_port()
    return f"http://{host}:{port}"


@pytest.fixture(scope="module")
def s3(endpoint: str) -> Iterator[Any]:
    """The bucket, written through s3fs with the endpoint; the environment points at it."""
    with pytest.MonkeyPatch.context() as mp:
        for key, value in {**_ENV, "AWS_ENDPOINT_URL": endpoint}.items():
            mp.setenv(key, value)
        fs = s3fs.S3FileSystem(endpoint_url=endpoint, skip_instance_cache=True)
        fs.mkdir(BUCKET)
        yield fs


def cartpole(path: Path, episodes: int = 3, seed: int = 0) -> Path:
    with RecordEvidence(gym.make("CartPole-v1"), path) as env:
        env.action_space.seed(seed)
        for e in range(episodes):
            env.reset(seed=seed + e)
            done = False
            while not done:
                _, _, term, trunc, _ = env.step(env.action_space.sample())
                done = term or trunc
    return path


@pytest.fixture(scope="module")
def runs(s3: Any, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Two CartPole files, locally in a directory and in ``s3://evidence/runs/``."""
    local = tmp_path_factory.mktemp("runs")
    for i, name in enumerate(["a.mcap", "b.mcap"]):
        cartpole(local / name, seed=10 * i)
        s3.put_file(str(local / name), f"{BUCKET}/runs/{name}")
    return local


def run(*args: str) -> tuple[int, str, str]:
    result = runner.invoke(app, list(args))
    if result.exception and not isinstance(result.exception, SystemExit):
        raise result.exception
    return result.exit_code, result.stdout, result.stderr


def test_check_report_replay_and_show_read_an_s3_prefix(runs: Path) -> None:
    url = f"s3://{BUCKET}/runs"
    code, out, err = run("check", url, "--format", "json")
    assert code == 0, err
    assert json.loads(out)["files"] == [f"{url}/a.mcap", f"{url}/b.mcap"]

    code, remote, err = run("report", url, "--format", "json")
    assert code == 0, err
    code, local, err = run("report", str(runs), "--format", "json")
    assert code == 0, err
    # the same report, the files named by their URLs
    assert remote == local.replace(str(runs), url)

    code, out, err = run("replay", f"{url}/b.mcap", "--format", "json")
    assert code == 0, err
    replayed = json.loads(out)
    assert {r["status"] for r in replayed["episodes"]} == {"identical"}
    assert len(replayed["episodes"]) == 3

    code, out, err = run("show", f"{url}/a.mcap", "--format", "json")
    assert code == 0, err
    assert json.loads(out)["file"] == f"{url}/a.mcap"


def test_export_reads_s3_and_writes_locally_or_to_s3(runs: Path, s3: Any, tmp_path: Path) -> None:
    url = f"s3://{BUCKET}/runs"
    code, _, err = run("export", url, "--out", str(tmp_path / "out"))
    assert code == 0, err
    steps = pq.read_table(tmp_path / "out" / "a.steps.parquet")
    assert set(steps.column("file").to_pylist()) == {f"{url}/a.mcap"}

    out = f"s3://{BUCKET}/export"
    code, text, err = run("export", url, "--out", out)
    assert code == 0, err
    assert out in text
    assert sorted(s3.ls(f"{BUCKET}/export", refresh=True)) == [
        f"{BUCKET}/export/a.steps.parquet",
        f"{BUCKET}/export/b.steps.parquet",
        f"{BUCKET}/export/episodes.parquet",
    ]
    with s3.open(f"{BUCKET}/export/episodes.parquet", "rb") as f:
        remote = pq.read_table(f)
    assert remote.equals(pq.read_table(tmp_path / "out" / "episodes.parquet"))

    code, _, err = run("export", url, "--out", out)  # the export is there already
    assert code == 2
    assert f"{out}/episodes.parquet: exists; pass --overwrite to replace" in err
    code, _, err = run("export", f"{url}/a.mcap", "--out", out, "--overwrite")
    assert code == 0, err
    assert f"{BUCKET}/export/b.steps.parquet" not in s3.ls(f"{BUCKET}/export", refresh=True)


@pytest.mark.parametrize(("viewer", "name"), [("foxglove", "a.foxglove.mcap"), ("rerun", "a.rrd")])
def test_viewer_exports_read_s3_and_refuse_a_url_output(
    runs: Path, endpoint: str, tmp_path: Path, viewer: str, name: str
) -> None:
    if viewer == "rerun":
        pytest.importorskip("rerun")
    pytest.importorskip("foxglove")
    url = f"s3://{BUCKET}/runs/a.mcap"
    code, text, err = run("export", url, "--to", viewer, "-o", str(tmp_path / name))
    assert code == 0, err
    local = export([runs / "a.mcap"], tmp_path / "local" / name, to=viewer)
    assert f"of {url} to {tmp_path / name}" in text
    remote = export(
        [url], tmp_path / "lib" / name, to=viewer, storage_options={"endpoint_url": endpoint}
    )
    assert remote.source == url
    assert (remote.episodes, remote.steps, remote.resets, remote.paths) == (
        local.episodes,
        local.steps,
        local.resets,
        local.paths,
    )
    out = f"s3://{BUCKET}/viewers/{name}"
    code, _, err = run("export", url, "--to", viewer, "-o", out)
    assert (code, err) == (
        2,
        f"episode-audit: error: --to {viewer}: --out must be a local file path, got the URL "
        f"{out!r}; export, then copy\n",
    )
    with pytest.raises(ConfigurationError, match=rf"^--to {viewer}: --out must be a local file"):
        export([url], out, to=viewer)


def test_recover_reads_and_writes_s3(s3: Any, tmp_path: Path) -> None:
    torn = REPO / "fixtures" / "torn.mcap"  # (a recorder killed after 6 chunks)
    (tmp_path / "torn.mcap").write_bytes(torn.read_bytes())
    s3.put_file(str(tmp_path / "torn.mcap"), f"{BUCKET}/torn/run.mcap")
    src, out = f"s3://{BUCKET}/torn/run.mcap", f"s3://{BUCKET}/fixed/run.mcap"
    # a torn file is scanned from its start, remotely as locally
    code, remote, err = run("report", src, "--format", "json")
    assert code == 0, err
    code, local, err = run("report", str(tmp_path / "torn.mcap"), "--format", "json")
    assert remote == local.replace(str(tmp_path / "torn.mcap"), src)
    assert json.loads(remote)["unfinished"], remote
    code, text, err = run("recover", src, "--out", out)
    assert code == 1, err  # the torn tail is lost
    assert out in text
    code, _, err = run("check", out)
    assert code == 0, err
    assert open_evidence(out).run_end["status"] == "recovered"  # type: ignore[index]
    code, _, err = run("recover", src, "--out", out)
    assert code == 2
    assert f"{out}: exists; pass --overwrite to replace it" in err


def test_library_takes_a_filesystem_or_storage_options(runs: Path, endpoint: str) -> None:
    fs = s3fs.S3FileSystem(endpoint_url=endpoint, key="testing", secret="testing")
    files = evidence_files([f"{BUCKET}/runs"], filesystem=fs)
    assert files == [f"s3://{BUCKET}/runs/a.mcap", f"s3://{BUCKET}/runs/b.mcap"]
    assert all(isinstance(f, RemoteFile) and f.fs is fs for f in files)
    again = pickle.loads(pickle.dumps(files[0]))  # as a worker process receives it
    assert (again, again.url, again.fs_path) == (files[0], files[0].url, files[0].fs_path)
    ev = open_evidence(f"s3://{BUCKET}/runs/a.mcap", storage_options={"endpoint_url": endpoint})
    assert ev.episodes().num_rows == 3
    local = open_evidence(runs / "a.mcap")
    assert ev.steps().equals(local.steps())
    assert [e.index for e in ev.iter_episodes()] == [0, 1, 2]
    result = report_inputs(files)
    assert result.readable == 2
    # the files evidence_files lists carry their filesystem into every library function
    assert check(files).files == files
    assert {r.status for r in replay(files).episodes} == {"identical"}
    with pytest.raises(EvidenceError, match=r"a\.mcap: cannot open: no such file, bucket"):
        open_evidence(f"s3://{BUCKET}/nothing/a.mcap", filesystem=fs)
    with pytest.raises(ConfigurationError, match=r"nothing: cannot read: no such file, bucket"):
        evidence_files([f"s3://{BUCKET}/nothing"], filesystem=fs)


def _large(path: Path) -> Path:
    """A file of over 20 MB: long episodes of 16 KB observations, a chunk per 10 steps."""
    space = gym.spaces.Box(0.0, 1.0, (4096,), np.float32)
    rng = np.random.default_rng(0)

    class Big(gym.Env[Any, Any]):
        observation_space = space
        action_space = gym.spaces.Discrete(2)

        def reset(self, *, seed: int | None = None, options: Any = None) -> tuple[Any, Any]:
            super().reset(seed=seed)
            self.t = 0
            return rng.random(4096, np.float32), {}

        def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
            self.t += 1
            return rng.random(4096, np.float32), 1.0, self.t >= 500, False, {}

    with RecordEvidence(Big(), path, block_steps=10) as env:
        for e in range(4):
            env.reset(seed=e)
            for _ in range(500):
                env.step(0)
    return path


def test_report_reads_a_small_part_of_a_large_file(
    s3: Any, server: CountingMotoServer, tmp_path: Path
) -> None:
    path = _large(tmp_path / "large.mcap")
    size = path.stat().st_size
    assert size >= 20 << 20
    s3.put_file(str(path), f"{BUCKET}/large/large.mcap")
    before = server.counter.served
    code, out, err = run("report", f"s3://{BUCKET}/large/large.mcap", "--format", "json")
    served = server.counter.served - before
    assert code == 0, err
    assert json.loads(out)["groups"][0]["episodes"] == 4
    assert served < size // 10, (served, size)


def test_a_progress_bar_s_total_reads_a_torn_file_s_end_only(
    s3: Any, server: CountingMotoServer, runs: Path, tmp_path: Path
) -> None:
    # a torn file made the total unknown, after scanning the whole of it
    data = _large(tmp_path / "large.mcap").read_bytes()
    torn = tmp_path / "torn.mcap"
    torn.write_bytes(data[: len(data) // 2])
    s3.put_file(str(torn), f"{BUCKET}/torn/torn.mcap")
    files = evidence_files([f"s3://{BUCKET}/runs/a.mcap", f"s3://{BUCKET}/torn/torn.mcap"])
    before = (server.counter.served, server.counter.requests)
    total = steps_total(files)
    served, requests = (n - b for n, b in zip(
        (server.counter.served, server.counter.requests), before, strict=True))  # fmt: skip
    assert total is not None and total > 0
    assert served < (2 << 20) < torn.stat().st_size // 4, served
    assert requests <= 4, requests  # (each file's two edges, as an open of a finished one)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _cli(env: dict[str, str], *args: str) -> subprocess.CompletedProcess[str]:
    base = {k: v for k, v in os.environ.items() if not k.startswith("AWS_")}
    return subprocess.run(
        [sys.executable, "-m", "episode_audit", *args],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=REPO,
        env={**base, "PYTHONPATH": str(REPO), **env},
    )


@pytest.mark.parametrize(
    ("case", "expected"),
    [
        ("unreachable", "cannot connect"),
        ("no credentials", "no credentials found"),
        ("no bucket", "no such file, bucket or prefix"),
        ("no key", "no such file, bucket or prefix"),
    ],
)
def test_bad_storage_is_one_line_and_exit_2(
    runs: Path, endpoint: str, case: str, expected: str
) -> None:
    env = {**_ENV, "AWS_ENDPOINT_URL": endpoint}
    url = f"s3://{BUCKET}/runs/a.mcap"
    if case == "unreachable":
        env["AWS_ENDPOINT_URL"] = f"http://127.0.0.1:{_free_port()}"
    elif case == "no credentials":
        del env["AWS_ACCESS_KEY_ID"], env["AWS_SECRET_ACCESS_KEY"]
    elif case == "no bucket":
        url = "s3://no-such-bucket/runs"
    else:
        url = f"s3://{BUCKET}/runs/zzz.mcap"
    start = time.monotonic()
    done = _cli(env, "report", url)
    assert time.monotonic() - start < 60
    assert done.returncode == 2, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1, done.stderr
    assert lines[0].startswith(f"episode-audit: error: {url}: cannot read: {expected}")
    assert "testing" not in done.stderr


def test_a_url_no_filesystem_here_reads_is_one_line_and_exit_2(tmp_path: Path) -> None:
    done = _cli({}, "check", "zip://x.mcap")  # (fsspec's zip needs the archive: none given)
    assert done.returncode == 2, done.stderr
    (line,) = done.stderr.splitlines()
    assert re.fullmatch(  # (fsspec < 2024.6 names the folder with a trailing slash)
        re.escape(
            "episode-audit: error: zip://x.mcap: cannot read zip:// URLs (IsADirectoryError: "
            f"[Errno 21] Is a directory: '{REPO}"
        )
        + "/?"
        + re.escape(
            "'); evidence is read from s3://, gs://, az:// and http(s):// (docs/storage.md), "
            "or copy the file here"
        ),
        line,
    ), line
    done = _cli({}, "check", "ftp://host-less/x.mcap")  # (no "Exception ignored in __del__")
    assert done.returncode == 2 and len(done.stderr.splitlines()) == 1, done.stderr
    assert done.stderr.startswith("episode-audit: error: ftp://host-less/x.mcap: cannot read ftp")
    if importlib.util.find_spec("paramiko") is None:
        done = _cli({}, "check", "sftp://host/x.mcap")
        assert done.returncode == 2 and done.stderr.strip().endswith(
            "needs an fsspec filesystem that is not installed: install the fsspec filesystem "
            "for sftp://"
        ), done.stderr


def test_urls_print_without_secrets() -> None:
    url = "https://user:pw@example.org/runs/a.mcap?X-Amz-Credential=AKIA&X-Amz-Signature=f00"
    assert shown_url(url) == "https://example.org/runs/a.mcap?…"


def test_a_storage_error_quoting_the_credentials_prints_without_them(endpoint: str) -> None:
    # botocore quotes the bucket it was given: "user:s3cret@bkt" (docs/security.md)
    url = f"s3://user:s3cret@{BUCKET}/runs/a.mcap?X-Amz-Signature=deadbeef"
    done = _cli({**_ENV, "AWS_ENDPOINT_URL": endpoint}, "check", url)
    assert done.returncode == 2, done.stderr
    assert len(done.stderr.strip().splitlines()) == 1, done.stderr
    assert "Invalid bucket name" in done.stderr  # (the message is there, its secrets not)
    for secret in ("s3cret", "user:", "deadbeef", "testing"):
        assert secret not in done.stderr, done.stderr


@pytest.fixture
def web(runs: Path) -> Iterator[str]:
    """The local runs directory served over HTTP on a free loopback port (with Range)."""
    from werkzeug.utils import send_from_directory
    from werkzeug.wrappers import Request

    @Request.application  # type: ignore[untyped-decorator]
    def files(request: Request) -> Any:
        return send_from_directory(runs, request.path.lstrip("/"), request.environ)

    srv = werkzeug_serving.make_server("127.0.0.1", 0, files, threaded=True)
    thread = threading.Thread(target=srv.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{srv.server_port}"
    finally:
        srv.shutdown()
        thread.join()


def test_an_http_folder_is_refused_naming_what_to_do(web: str) -> None:
    code, _, err = run("report", f"{web}/")
    assert code == 2
    assert err == (
        f"episode-audit: error: {web}/: HTTP lists no folder: name each file's URL, or read "
        "the folder from s3://, gs:// or az://\n"
    )


def test_a_server_without_ranges_is_named_with_what_to_do(runs: Path) -> None:
    from functools import partial
    from http.server import HTTPServer, SimpleHTTPRequestHandler

    class Quiet(SimpleHTTPRequestHandler):
        def log_message(self, *args: Any) -> None:
            pass

    srv = HTTPServer(("127.0.0.1", 0), partial(Quiet, directory=str(runs)))
    thread = threading.Thread(target=srv.serve_forever, daemon=True)
    thread.start()
    try:
        url = f"http://127.0.0.1:{srv.server_port}/a.mcap"
        code, _, err = run("check", url)
    finally:
        srv.shutdown()
        thread.join()
        srv.server_close()
    assert code == 2
    assert err.startswith(f"episode-audit: error: {url}: cannot ") and err.rstrip().endswith(
        "the HTTP server does not answer Range requests, which reading needs: serve the file "
        "from one that does (nginx, S3, any object store), or download it"
    ), err


def test_http_urls_are_read_by_ranges(web: str, runs: Path) -> None:
    code, out, err = run("report", f"{web}/a.mcap", "--format", "json")
    assert code == 0, err
    code, local, err = run("report", str(runs / "a.mcap"), "--format", "json")
    assert out == local.replace(str(runs), web)
    code, _, err = run("check", f"{web}/zzz.mcap")
    assert code == 2
    assert err.startswith(f"episode-audit: error: {web}/zzz.mcap: cannot read: no such file")


def test_http_access_denied_and_no_connection_are_told_apart_from_not_found() -> None:
    from http.server import BaseHTTPRequestHandler, HTTPServer

    class Forbidden(BaseHTTPRequestHandler):
        def do_HEAD(self) -> None:
            self.send_response(403)
            self.end_headers()

        do_GET = do_HEAD

        def log_message(self, *args: Any) -> None:
            pass

    srv = HTTPServer(("127.0.0.1", 0), Forbidden)
    thread = threading.Thread(target=srv.serve_forever, daemon=True)
    thread.start()
    try:
        url = f"http://127.0.0.1:{srv.server_port}/a.mcap"
        code, _, err = run("check", url)
        assert code == 2
        assert err.startswith(f"episode-audit: error: {url}: cannot read: access denied (HTTP 403)")
    finally:
        srv.shutdown()
        srv.server_close()
    url = f"http://127.0.0.1:{_free_port()}/a.mcap"
    code, _, err = run("check", url)
    assert code == 2 and err.startswith(f"episode-audit: error: {url}: cannot read: cannot connect")


@pytest.mark.parametrize(("url", "extra"), [("gs://b/k.mcap", "gcs"), ("az://c/k.mcap", "azure")])
def test_a_scheme_without_its_filesystem_names_the_extra(url: str, extra: str) -> None:
    pytest.importorskip("fsspec")
    module = {"gcs": "gcsfs", "azure": "adlfs"}[extra]
    if importlib.util.find_spec(module):
        pytest.skip("its filesystem is installed")
    code, _, err = run("show", url)
    assert code == 2
    assert err == (
        f"episode-audit: error: {url}: reading {url[:2]}:// URLs needs an fsspec filesystem "
        f"that is not installed: pip install 'episode-audit[{extra}]'\n"
    )


def test_record_uploads_the_finished_file(s3: Any, tmp_path: Path) -> None:
    out = tmp_path / "rec.mcap"
    code, text, err = run(
        "record",
        "CartPole-v1",
        "--out",
        str(out),
        "--episodes",
        "2",
        "--upload",
        f"s3://{BUCKET}/rec/",
    )
    assert code == 0, err
    assert f"uploaded {out} to s3://{BUCKET}/rec/rec.mcap" in text
    assert s3.cat_file(f"{BUCKET}/rec/rec.mcap") == out.read_bytes()
    code, _, err = run("check", f"s3://{BUCKET}/rec/rec.mcap")
    assert code == 0, err
    code, _, err = run("record", "CartPole-v1", "--out", str(tmp_path / "b.mcap"), "--upload", "x/")
    assert code == 2
    assert "--upload: expected a URL" in err
    assert not (tmp_path / "b.mcap").exists()
    # an upload never replaces a file there without --overwrite; refused before recording
    again = tmp_path / "again" / "rec.mcap"
    code, _, err = run(
        "record", "CartPole-v1", "--out", str(again), "--upload", f"s3://{BUCKET}/rec/"
    )
    assert code == 2 and not again.exists()
    assert err == (
        f"episode-audit: error: --upload: s3://{BUCKET}/rec/rec.mcap: exists; pass --overwrite "
        "to replace it\n"
    )
    assert s3.cat_file(f"{BUCKET}/rec/rec.mcap") == out.read_bytes()
    args = ["--episodes", "1", "--upload", f"s3://{BUCKET}/rec/", "--overwrite"]
    code, _, err = run("record", "CartPole-v1", "--out", str(again), *args)
    assert code == 0, err
    assert s3.cat_file(f"{BUCKET}/rec/rec.mcap") == again.read_bytes()


@pytest.mark.parametrize("command", ["check", "report", "replay"])
def test_a_viewer_export_under_a_prefix_is_left_out_in_one_line(
    runs: Path, s3: Any, tmp_path: Path, command: str
) -> None:
    """As in a local folder: the export was read as an unreadable input (exit 2)."""
    pytest.importorskip("foxglove")
    from episode_audit.export import export

    viewer = tmp_path / "a.foxglove.mcap"
    export([runs / "a.mcap"], viewer, to="foxglove")
    for name in ("a.mcap", "a.foxglove.mcap"):
        s3.put_file(str(runs / name if name == "a.mcap" else viewer), f"{BUCKET}/mixed/{name}")
    s3.put_file(str(viewer), f"{BUCKET}/viewers/a.foxglove.mcap")
    url = f"s3://{BUCKET}/mixed"
    code, out, err = run(command, url, "--format", "json")
    assert code == 0, err
    assert err == (
        "episode-audit: note: left out 1 viewer export(s) found in the directories given "
        f"({url}/a.foxglove.mcap)\n"
    )
    assert json.loads(out)["unreadable"] == []
    code, _, err = run(command, f"s3://{BUCKET}/viewers")
    assert code == 2
    assert err.startswith(
        f"episode-audit: error: s3://{BUCKET}/viewers: no evidence files under this prefix: its "
        "1 *.mcap file(s) are viewer exports"
    ), err
    code, _, err = run(command, f"{url}/a.foxglove.mcap")  # named, it is still refused
    assert code == 2 and "(a viewer file), not evidence" in err, err
