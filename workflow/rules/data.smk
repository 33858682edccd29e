# Data: generate synthetic scenes; SfM for image-only datasets.


def synth_args(wildcards):
    params = {**config["synthetic"], **scene_config(wildcards.scene)["synthetic"]}
    return (f"{params['kind']} --views {params['views']} --width {params['width']} --height {params['height']} "
            f"--seed {params['seed']} --arc {params['arc']}")


rule synth:
    output:
        directory(LAYOUT.input("{scene}")),
    params:
        args=synth_args,
    log:
        LAYOUT.log("{scene}", "synth"),
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
        s=lambda wc: config["sfm"],
        per_image=lambda wc: "" if config["sfm"]["single_camera"] else " --per-image-camera",
    log:
        LAYOUT.log("{scene}", "sfm"),
    threads: lambda wc: config["sfm"]["threads"] if config["sfm"]["threads"] > 0 else workflow.cores
    conda:
        CONDA_ENV
    shell:
        "{EVE3D} sfm {input} {output} --matcher {params.s[matcher]} --camera-model {params.s[camera_model]}"
        " --max-image-size {params.s[max_image_size]} --min-registered-fraction {params.s[min_registered_fraction]}"
        " --seed {params.s[seed]} --threads {params.s[threads]}"
        "{params.per_image} > {log} 2>&1"
