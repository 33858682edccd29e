# Depth priors per view: the oracle (exact depth of a scene with a GT mesh), or a stereo
# backend run on virtual stereo pairs (the photo, and a right view rendered by the pretrained model).


rule stereo_render:
    input:
        scene=posed_dataset,
        model=LAYOUT.model("{scene}", PRETRAIN),
        tone=LAYOUT.tone_curve("{scene}"),  # read beside the model; the photos are matched through it
    output:
        directory(LAYOUT.stereo("{scene}")),
    params:
        config=lambda wc: render_job(wc.scene),
    log:
        LAYOUT.log("{scene}", "stereo_render"),
    benchmark:
        LAYOUT.benchmark("{scene}", "stereo_render"),
    priority: 2  # on the longest chain (workflow/rules/train.smk)
    resources:
        **ON_GAUSSIAN_DEVICE,
    conda:
        CONDA_ENV
    shell:
        "{EVE3D} stereo-render --scene {input.scene} --model {input.model} --out {output}"
        " --config {params.config} > {log} 2>&1"


rule stereo_depth:
    input:
        unpack(stereo_depth_inputs),
    output:
        directory(LAYOUT.priors("{scene}", "{backend}")),
    wildcard_constraints:
        backend="|".join(PRIOR_BACKENDS),
    params:
        args=stereo_depth_args,
        config=lambda wc: job_config("stereo"),
    log:
        LAYOUT.log("{scene}", "stereo_depth", "{backend}"),
    benchmark:
        LAYOUT.benchmark("{scene}", "stereo_depth", "{backend}"),
    # a network (onnxruntime) a training job's share of the cores; a matcher one
    threads: lambda wc: training_threads() if PRIOR_BACKENDS[wc.backend].device == "gpu" else 1
    priority: 2  # on the longest chain (workflow/rules/train.smk)
    resources:
        **device_resources(lambda wc: PRIOR_BACKENDS[wc.backend].device),
    conda:
        CONDA_ENV
    shell:
        "OMP_NUM_THREADS={threads} {EVE3D} stereo-depth --backend {wildcards.backend} --scene {input.scene}"
        " --out {output} {params.args} --config {params.config} > {log} 2>&1"
