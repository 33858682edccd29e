"""The workflow's logger plugin (eve3d.core.progress, moving to workflow/logger/snakemake_logger_plugin_eve3d/progress.py)."""
import re


def test_progress_shows_job_starts_ends_and_the_training_bar(tmp_path):
    """The logger plugin's handler: a line per job start and end with its stage, scene,
    method and wall time; the running job's latest bar from its log (no drawing), printed
    once while it does not change; errors as Snakemake formats them."""
    import io
    import logging
    import time

    from snakemake_interface_logger_plugins.common import LogEvent

    from snakemake_logger_plugin_eve3d.progress import ProgressHandler, latest_progress

    log = tmp_path / "joint_eve3d.log"
    log.write_text("eve3d: loading images\neve3d:  10%|#         | 10/100 [00:01<00:09, 9.9it/s, loss=0.2, psnr=12.00]"
                   "\reve3d:  20%|##        | 20/100 [00:02<00:08, 9.9it/s, loss=0.1000, n=512, psnr=18.31]")
    assert latest_progress(log) == "eve3d: 20/100 [00:02<00:08, 9.9it/s, loss=0.1000, n=512, psnr=18.31]"
    assert latest_progress(tmp_path / "missing.log") is None

    def record(event, level=logging.INFO, msg="", **fields):
        r = logging.LogRecord("snakemake", level, "", 0, msg, None, None)
        r.event = event
        r.__dict__.update(fields)
        return r

    out = io.StringIO()
    handler = ProgressHandler(out, interval=0.2)
    handler.emit(record(LogEvent.PROGRESS, done=3, total=9))
    handler.emit(record(LogEvent.JOB_INFO, jobid=7, rule_name="joint", wildcards={"scene": "tiny", "method": "eve3d"},
                        log=[str(log)]))
    time.sleep(1.5)  # the poller reads the log; the line does not change, so it is printed once
    handler.emit(record(LogEvent.JOB_FINISHED, job_id=7))
    handler.emit(record(None, logging.INFO, "Select jobs to execute..."))  # chatter: not shown
    handler.emit(record(LogEvent.ERROR, logging.ERROR, "WorkflowError: at least one job failed"))
    handler.close()
    lines = out.getvalue().splitlines()
    assert lines[0] == "[3/9] start   joint tiny eve3d"
    assert lines[1] == "        joint tiny eve3d: eve3d: 20/100 [00:02<00:08, 9.9it/s, loss=0.1000, n=512, psnr=18.31]"
    assert re.fullmatch(r"\[4/9\] done    joint tiny eve3d  [12] s", lines[2]), lines
    assert lines[3:] == ["WorkflowError: at least one job failed"]
