# eve3d workflow: `snakemake -c2` runs every scene of config/config.yaml; see README.md.
configfile: "config/config.yaml"
report: "workflow/report/workflow.rst"


include: "workflow/rules/common.smk"
include: "workflow/rules/data.smk"
include: "workflow/rules/depth.smk"
include: "workflow/rules/train.smk"
include: "workflow/rules/mesh.smk"
include: "workflow/rules/evaluate.smk"


rule all:
    input:
        LAYOUT.summary(),
        mesh_files(),
        LAYOUT.report_pages() / "summary.html",
    default_target: True


onsuccess:
    LAYOUT.failures().unlink(missing_ok=True)  # a failure listed by an earlier run is resolved


onerror:
    # Failed jobs (with --keep-going the other scenes went on): the summary and the report list
    # each scene and method left without metrics, with its job's first error line and log.
    import subprocess
    from eve3d.failures import failed_jobs, failed_rows, write_failures

    _failed = failed_rows(LAYOUT, [(s, m) for s in SCENES for m in scene_methods(s)], failed_jobs(log))
    write_failures(LAYOUT.failures(), _failed)
    _metrics = [Path(p) for p in metrics_files() + pretrain_metrics() if Path(p).exists()]
    subprocess.run(f"{EVE3D} summary {' '.join(shlex.quote(str(p)) for p in _metrics)} --failed {LAYOUT.failures()}"
                   f" --out {LAYOUT.summary()}", shell=True)
    if LAYOUT.summary().exists() and _metrics:  # dated before its inputs, so that the next run redoes it
        _before = min(p.stat().st_mtime for p in _metrics) - 1
        os.utime(LAYOUT.summary(), (_before, _before))
    subprocess.run(f"{EVE3D} report --results {LAYOUT.root} --out {LAYOUT.report_pages()} {report_args(None)}"
                   f" > {LAYOUT.logs() / 'report_pages.log'} 2>&1", shell=True)
    for _row in _failed:
        print(f"failed: {_row['scene']} {_row['method']}: {_row['failed']} (log: {_row['log']})", file=sys.stderr)
    print(f"summary: {LAYOUT.summary()}; report pages: {LAYOUT.report_pages()}", file=sys.stderr)
