# Depth priors per view: the oracle (exact depth of a scene with a GT mesh), or a stereo
# backend run on virtual stereo pairs (the photo, and a right view rendered by the pretrained model).


rule stereo_render:
    input:
        scene=posed_dataset,
        model=f"{RESULTS}/{{scene}}/pretrain/point_cloud.ply",
        tone=f"{RESULTS}/{{scene}}/pretrain/{TONE_FILE}",  # read beside the model; the photos are matched through it
    output:
        directory(f"{RESULTS}/{{scene}}/stereo"),
    params:
        config=lambda wc: render_job(),
    log:
        f"{RESULTS}/logs/{{scene}}/stereo_render.log",
    benchmark:
        f"{RESULTS}/benchmarks/{{scene}}/stereo_render.tsv",
    conda:
        CONDA_ENV
    shell:
        "{EVE3D} stereo-render --scene {input.scene} --model {input.model} --out {output}"
        " --config {params.config} > {log} 2>&1"


rule stereo_depth:
    input:
        unpack(stereo_depth_inputs),
    output:
        directory(f"{RESULTS}/{{scene}}/priors/{{backend}}"),
    wildcard_constraints:
        backend="oracle|sgbm|onnx",
    params:
        args=stereo_depth_args,
        config=lambda wc: job_config("stereo"),
    log:
        f"{RESULTS}/logs/{{scene}}/stereo_depth_{{backend}}.log",
    benchmark:
        f"{RESULTS}/benchmarks/{{scene}}/stereo_depth_{{backend}}.tsv",
    conda:
        CONDA_ENV
    shell:
        "{EVE3D} stereo-depth --backend {wildcards.backend} --scene {input.scene} --out {output} {params.args}"
        " --config {params.config}"
        " > {log} 2>&1"
