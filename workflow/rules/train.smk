# Gaussian training: the pretrain stage and the joint stage of each trained method. Each job
# takes every core it is given (OpenMP in the CPU rasteriser); on a GPU the cores matter less.


rule pretrain:
    input:
        posed_dataset,
    output:
        model=f"{RESULTS}/{{scene}}/pretrain/point_cloud.ply",
        metrics=f"{RESULTS}/{{scene}}/pretrain/train_metrics.json",
        tone=f"{RESULTS}/{{scene}}/pretrain/{TONE_FILE}",
    params:
        config=lambda wc: training_config("pretrain"),
    log:
        f"{RESULTS}/logs/{{scene}}/pretrain.log",
    benchmark:
        f"{RESULTS}/benchmarks/{{scene}}/pretrain.tsv",
    threads: workflow.cores
    conda:
        CONDA_ENV
    shell:
        "OMP_NUM_THREADS={threads} {EVE3D} pretrain --scene {input} --out {RESULTS}/{wildcards.scene}/pretrain --config {params.config}"
        " > {log} 2>&1"


rule joint:
    input:
        unpack(joint_inputs),
    output:
        model=f"{RESULTS}/{{scene}}/{{method}}/point_cloud.ply",
        depth=directory(f"{RESULTS}/{{scene}}/{{method}}/depth"),
        metrics=f"{RESULTS}/{{scene}}/{{method}}/train_metrics.json",
    wildcard_constraints:
        method="|".join(map(re.escape, TRAINED)),
    params:
        config=lambda wc: training_config("joint", wc.scene, wc.method),
        priors=lambda wc, input: f"--priors {input.priors}" if "priors" in input.keys() else "",
    log:
        f"{RESULTS}/logs/{{scene}}/joint_{{method}}.log",
    benchmark:
        f"{RESULTS}/benchmarks/{{scene}}/joint_{{method}}.tsv",
    threads: workflow.cores
    conda:
        CONDA_ENV
    shell:
        "OMP_NUM_THREADS={threads} {EVE3D} joint --method {wildcards.method} --scene {input.scene}"
        " --out {RESULTS}/{wildcards.scene}/{wildcards.method} {params.priors} --config {params.config} > {log} 2>&1"
