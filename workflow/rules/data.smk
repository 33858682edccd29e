# Data: generate synthetic scenes; SfM for image-only datasets.


def synth_args(wildcards):
    """The kind, and the `synthetic` section with the scene's own keys over it."""
    own = dict(scene_config(wildcards.scene)["synthetic"])
    kind = own.pop("kind")
    return f"{kind} --config " + job_config(synthetic={**config["synthetic"], **own})


rule synth:
    output:
        directory(LAYOUT.input("{scene}")),
    params:
        args=synth_args,
    log:
        LAYOUT.log("{scene}", "synth"),
    benchmark:
        LAYOUT.benchmark("{scene}", "synth"),
    conda:
        CONDA_ENV
    shell:
        "{EVE3D} synth {params.args} {output} > {log} 2>&1"


rule sfm:
    input:
        raw_dataset,
    output:
        directory(LAYOUT.sfm("{scene}")),
    params:
        config=lambda wc: job_config("sfm"),
    log:
        LAYOUT.log("{scene}", "sfm"),
    benchmark:
        LAYOUT.benchmark("{scene}", "sfm"),
    threads: lambda wc: config["sfm"]["threads"] if config["sfm"]["threads"] > 0 else all_cores()
    conda:
        CONDA_ENV
    shell:
        "OMP_NUM_THREADS={threads} {EVE3D} sfm {input} {output} --config {params.config} > {log} 2>&1"
