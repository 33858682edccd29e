# Metrics per scene and method, and the summary table over all of them; before any
# training, the check that a benchmark scene's ground truth lines up with its cameras.


rule check_ground_truth:
    input:
        unpack(ground_truth_inputs),
    output:
        LAYOUT.ground_truth_check("{scene}"),
    params:
        args=ground_truth_args,
        config=check_job,
    log:
        LAYOUT.log("{scene}", "check_ground_truth"),
    conda:
        CONDA_ENV
    shell:
        # the message that names the misplaced file is the log's last line: show it
        "{EVE3D} evaluate --check --scene {input.scene} --out {output} {params.args} --config {params.config}"
        " > {log} 2>&1 || {{ tail -n 3 {log} >&2; exit 1; }}"


rule evaluate:
    input:
        unpack(evaluate_inputs),
    output:
        LAYOUT.metrics("{scene}", "{method}"),
    params:
        args=evaluate_args,
    log:
        LAYOUT.log("{scene}", "evaluate", "{method}"),
    benchmark:
        LAYOUT.benchmark("{scene}", "evaluate", "{method}"),
    priority: after_training
    conda:
        CONDA_ENV
    shell:
        "{EVE3D} evaluate --scene {input.scene} --out {output}"
        " --scene-name {wildcards.scene} --method {wildcards.method} {params.args} > {log} 2>&1"


rule summary:
    input:
        metrics=metrics_files(),
        novel_views=pretrain_metrics(),
    output:
        LAYOUT.summary(),
    log:
        LAYOUT.logs() / "summary.log",
    conda:
        CONDA_ENV
    shell:
        # the table goes to the log too: the workflow prints it last (show_summary)
        "{EVE3D} summary {input.metrics} {input.novel_views} --out {output} > {log} 2>&1"


rule report_pages:
    input:
        summary=LAYOUT.summary(),
        meshes=mesh_files(),
    output:
        summary=report(LAYOUT.report_pages() / "summary.html", caption="../report/summary.rst", category="1 Summary"),
        charts=report(directory(LAYOUT.report_pages() / "charts"), patterns=["{chart}.png"],
                      caption="../report/charts.rst", category="2 Charts", labels={"chart": "{chart}"}),
        views3d=report(directory(LAYOUT.report_pages() / "scenes3d"), patterns=["{scene}.html"],
                       caption="../report/views3d.rst", category="3 Scenes in 3D", labels={"scene": "{scene}"}),
        scenes=report(directory(LAYOUT.report_pages() / "scenes"), patterns=["{scene}/{method}.png"],
                      caption="../report/scenes.rst", category="4 Scene sheets", subcategory="{scene}",
                      labels={"scene": "{scene}", "method": "{method}"}),
        runtimes=report(LAYOUT.report_pages() / "runtimes.html", caption="../report/runtimes.rst",
                        category="5 Run times"),
    params:
        args=report_args,
        results=LAYOUT.root,
        out=LAYOUT.report_pages(),
    log:
        LAYOUT.logs() / "report_pages.log",
    conda:
        CONDA_ENV
    shell:
        "{EVE3D} report --results {params.results} --out {params.out} {params.args} > {log} 2>&1"


def show_summary():
    """The workflow's onsuccess: the summary table last, below the jobs' lines, when this run
    wrote it (a run that made one mesh prints none)."""
    from eve3d.report import run_show_summary

    if LAYOUT.summary().is_file() and LAYOUT.summary().stat().st_mtime >= STARTED:
        run_show_summary(summary=LAYOUT.summary())


def report_failures(log):
    """The workflow's onerror: failed jobs (with --keep-going the other scenes went on). The
    summary and the report list each scene and method left without metrics, with its job's
    first error line and log (``log``: Snakemake's log file)."""
    import subprocess
    from eve3d.core.failures import failed_jobs, failed_rows, write_failures

    failed = failed_rows(LAYOUT, [(s, m) for s in SCENES for m in scene_methods(s)], failed_jobs(log))
    write_failures(LAYOUT.failures(), failed)
    metrics = [Path(p) for p in metrics_files() + pretrain_metrics() if Path(p).exists()]
    subprocess.run(f"{EVE3D} summary {' '.join(shlex.quote(str(p)) for p in metrics)} --failed {LAYOUT.failures()}"
                   f" --out {LAYOUT.summary()}", shell=True)
    if LAYOUT.summary().exists() and metrics:  # dated before its inputs, so that the next run redoes it
        before = min(p.stat().st_mtime for p in metrics) - 1
        os.utime(LAYOUT.summary(), (before, before))
    subprocess.run(f"{EVE3D} report --results {LAYOUT.root} --out {LAYOUT.report_pages()} {report_args(None)}"
                   f" > {LAYOUT.logs() / 'report_pages.log'} 2>&1", shell=True)
    for row in failed:
        print(f"failed: {row['scene']} {row['method']}: {row['failed']} (log: {row['log']})", file=sys.stderr)
    print(f"summary: {LAYOUT.summary()}; report pages: {LAYOUT.report_pages()}", file=sys.stderr)
