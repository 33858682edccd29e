"""eve3d.core.failures: failed jobs read from Snakemake's logs, each job log's first error line, the summary's rows."""
import json
from pathlib import Path

from eve3d.core.failures import failed_jobs, failed_rows, first_error_line, write_failures
from eve3d.core.layout import Layout


def started(rule: str, jobid: int, log: str, wildcards: str) -> str:
    """A job's start as Snakemake 9 logs it (with its log, whether it fails or not)."""
    return (f"[Tue Dec  1 10:0{jobid}:00 2026]\nlocalrule {rule}:\n    input: results/tiny/input\n    log: {log}\n"
            f"    jobid: {jobid}\n    reason: Missing output files: results/tiny/x\n    wildcards: {wildcards}\n"
            f"    threads: 2\n    resources: tmpdir=/tmp\n\n")


def error(rule: str, jobid: int, log: str | None, command: str = "eve3d joint results/tiny") -> str:
    """A failed job as Snakemake 9 logs it (``_format_job_error``), with a log or without one."""
    log_line = f"    log: {log} (check log file(s) for error details)\n" if log else ""
    return (f"[Tue Dec  1 10:0{jobid}:30 2026]\nError in rule {rule}:\n    jobid: {jobid}\n"
            f"    input: results/tiny/input\n    output: results/tiny/{rule}/out.ply\n{log_line}"
            f"    shell:\n        {command} > {log} 2>&1\n        (command exited with non-zero exit code)\n\n")


def test_failed_jobs_are_the_error_blocks_of_the_logs_in_order_once_each(tmp_path):
    """Only "Error in rule" blocks count (a job's start lists its log too), each with its
    ``log:`` path (not the "(check log file(s) …)" after it); a block without a log is left
    out; the same job failed in two runs' logs is listed once, in the order they failed;
    paths that cannot be read (missing, a folder) are skipped."""
    joint, mesh = "results/logs/tiny/joint_pgsr.log", "results/logs/tiny/mesh_pgsr.log"
    stereo = "results/logs/room/stereo_depth_sgbm.log"
    first = tmp_path / "2026-12-01T100000.1.snakemake.log"
    first.write_text("Assuming unrestricted shared filesystem usage.\nProvided cores: 2\nSelect jobs to execute...\n"
                     + started("mesh", 3, mesh, "scene=tiny, method=pgsr") + started("joint", 4, joint, "scene=tiny")
                     + error("joint", 4, joint) + error("summary", 6, None)
                     + error("stereo_depth", 5, stereo, "eve3d stereo-depth results/room")
                     + "Shutting down, this might take some time.\nExiting because a job execution failed. "
                       "Look below for error messages\n"
                       "Complete log: .snakemake/log/2026-12-01T100000.1.snakemake.log\n")
    rerun = tmp_path / "2026-12-01T110000.1.snakemake.log"   # the same joint fails again, then the mesh
    rerun.write_text(started("joint", 1, joint, "scene=tiny") + error("joint", 1, joint) + error("mesh", 2, mesh))
    (tmp_path / "folder.log").mkdir()
    jobs = failed_jobs([tmp_path / "nowhere.log", first, str(tmp_path / "folder.log"), rerun])
    assert jobs == [("joint", Path(joint)), ("stereo_depth", Path(stereo)), ("mesh", Path(mesh))]
    assert failed_jobs([rerun, first]) == [("joint", Path(joint)), ("mesh", Path(mesh)), ("stereo_depth", Path(stereo))]
    assert failed_jobs([tmp_path / "nowhere.log"]) == [] and failed_jobs([]) == []
    cut = tmp_path / "cut.log"  # a log that ends mid-line: the next log's first block is still read
    cut.write_text(started("joint", 1, joint, "scene=tiny").rstrip("\n"))
    (tmp_path / "next.log").write_text(error("mesh", 2, mesh).split("\n", 1)[1])  # "Error in rule" its first line
    assert failed_jobs([cut, tmp_path / "next.log"]) == [("mesh", Path(mesh))]
    # a successful run's log: its jobs started and finished, none failed
    (tmp_path / "ok.log").write_text(started("joint", 1, joint, "scene=tiny") + "Finished jobid: 1 (Rule: joint)\n")
    assert failed_jobs([tmp_path / "ok.log"]) == []


def test_first_error_line_prefers_eve3ds_own_then_the_exception_then_error_words(tmp_path):
    log = tmp_path / "job.log"

    def first(text: str | bytes) -> str:
        log.write_bytes(text if isinstance(text, bytes) else text.encode())
        return first_error_line(log)

    traceback = ("Traceback (most recent call last):\n  File \"/work/eve3d/joint.py\", line 40, in run\n"
                 "    raise RuntimeError(\"the loss is NaN\")\n")
    # eve3d's own "prog: error: message" line wins over an exception, the first of them
    assert first("joint:  10%|#| 10/100\r\njoint:  20%|##| 20/100\r\n" + traceback
                 + "RuntimeError: the loss is NaN\neve3d joint: error: the loss is NaN at step 20\n"
                   "eve3d joint: error: a second one\n") == "eve3d joint: error: the loss is NaN at step 20"
    # else the last exception line: of a chain, the one that ended the job; dotted names too
    oom = "torch.OutOfMemoryError: CUDA out of memory. Tried to allocate 2.00 GiB"
    assert first(traceback + "RuntimeError: the loss is NaN\n\nDuring handling of the above exception, another "
                 "exception occurred:\n\n" + traceback + oom + "\nwrote nothing\n") == oom
    # no exception line (the job was killed mid-traceback, or by the kernel): the last line with an error word
    assert first("step 1\n" + traceback) == "Traceback (most recent call last):"
    assert first("pretrain: 40%|####| 40/100\r/bin/bash: line 1: 4242 Killed  eve3d pretrain results/tiny\r\n"
                 "pretrain: 41%|####| 41/100\n") == "/bin/bash: line 1: 4242 Killed  eve3d pretrain results/tiny"
    # else the last line; lines split at \r (progress bars) as well as \n, stripped, blank ones skipped
    assert first("  loading\r\n\r\nmesh: 100%|#####| 8/8 \r\n   \n") == "mesh: 100%|#####| 8/8"
    # bytes that are not UTF-8 are replaced, not an exception
    assert first(b"step 1\n\xff\xfe\nValueError: bad \xe9 value\n") == "ValueError: bad \ufffd value"
    assert first("") == first(" \n\r\n") == "(empty log: the job was killed before it wrote anything?)"
    assert first_error_line(tmp_path / "missing.log") == f"(no log at {tmp_path / 'missing.log'})"
    assert first_error_line(tmp_path) == f"(no log at {tmp_path})"


def test_failed_rows_name_the_first_job_each_row_waited_for_and_write_as_json(tmp_path):
    """A scene's own job (pretrain) fails every method of that scene without metrics, and
    only of that scene; a job named after another method does not; a job named after no
    method (a backend) does; the first failed job that fits is named."""
    layout = Layout(tmp_path / "results")
    layout.metrics("tiny", "oracle").parent.mkdir(parents=True)
    layout.metrics("tiny", "oracle").write_text("{}")
    logs = {"pretrain": layout.log("tiny", "pretrain"), "joint": layout.log("tiny", "joint", "pgsr"),
            "stereo_depth": layout.log("room", "stereo_depth", "sgbm"), "mesh": layout.log("room", "mesh", "pgsr")}
    for log in logs.values():
        log.parent.mkdir(parents=True, exist_ok=True)
    logs["pretrain"].write_text("pretrain:   5%|| 5/100\nMemoryError\n")
    logs["stereo_depth"].write_text("eve3d stereo-depth: error: /data/003.png: corrupt or unreadable image\n")
    # logs["joint"] and logs["mesh"] never written: the job died before its shell redirected
    expected = [(scene, method) for scene in ("tiny", "room") for method in ("oracle", "pgsr", "stereo-tsdf")]
    jobs = [("joint", logs["joint"]), ("pretrain", logs["pretrain"]), ("mesh", logs["mesh"]),
            ("stereo_depth", logs["stereo_depth"]), ("summary", layout.logs() / "summary.log")]
    rows = failed_rows(layout, expected, jobs)
    assert [(r["scene"], r["method"], r["failed"], r["log"]) for r in rows] == [
        ("tiny", "pgsr", f"joint: (no log at {logs['joint']})", str(logs["joint"])),   # its own job, failed first
        ("tiny", "stereo-tsdf", "pretrain: MemoryError", str(logs["pretrain"])),
        ("room", "oracle", "stereo_depth: eve3d stereo-depth: error: /data/003.png: corrupt or unreadable image",
         str(logs["stereo_depth"])),
        ("room", "pgsr", f"mesh: (no log at {logs['mesh']})", str(logs["mesh"])),
        ("room", "stereo-tsdf", "stereo_depth: eve3d stereo-depth: error: /data/003.png: corrupt or unreadable image",
         str(logs["stereo_depth"]))]
    assert failed_rows(layout, expected, []) == []
    assert failed_rows(layout, [("tiny", "oracle")], jobs) == []   # it has its metrics

    out = layout.failures()
    write_failures(out, rows)
    assert json.loads(out.read_text()) == rows
    write_failures(out, [])   # replaced whole, no temporary file left beside it
    assert json.loads(out.read_text()) == [] and sorted(p.name for p in out.parent.iterdir()) == ["failed.json", "logs",
                                                                                                 "tiny"]
