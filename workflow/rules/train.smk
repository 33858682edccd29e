# Gaussian training: the pretrain stage and the joint stage of each trained method. Each job
# takes every core it is given (OpenMP in the CPU rasteriser); on a GPU the cores matter less.


rule pretrain:
    input:
        scene=posed_dataset,
        checked=ground_truth_checked,
    output:
        model=LAYOUT.model("{scene}", PRETRAIN),
        metrics=LAYOUT.train_metrics("{scene}", PRETRAIN),
        tone=LAYOUT.tone_curve("{scene}"),
    params:
        config=lambda wc: training_job("pretrain", wc.scene),
        out=lambda wc: LAYOUT.pretrain(wc.scene),
    log:
        LAYOUT.log("{scene}", "pretrain"),
    benchmark:
        LAYOUT.benchmark("{scene}", "pretrain"),
    # Every core, not a share: on 2 cores one-thread jobs side by side made the demo slower
    # (docs/development.md, "Where a run's time goes")
    threads: all_cores()
    resources:
        **ON_GAUSSIAN_DEVICE,
    conda:
        CONDA_ENV
    shell:
        "OMP_NUM_THREADS={threads} {EVE3D} pretrain --scene {input.scene} --out {params.out} --config {params.config}"
        " > {log} 2>&1"


rule joint:
    input:
        unpack(joint_inputs),
    output:
        model=LAYOUT.model("{scene}", "{method}"),
        depth=directory(LAYOUT.depth("{scene}", "{method}")),
        metrics=LAYOUT.train_metrics("{scene}", "{method}"),
    wildcard_constraints:
        method="|".join(map(re.escape, TRAINED)),
    params:
        config=lambda wc: training_job("joint", wc.scene, wc.method),
        out=lambda wc: LAYOUT.method(wc.scene, wc.method),
        priors=lambda wc, input: f"--priors {input.priors}" if "priors" in input.keys() else "",
    log:
        LAYOUT.log("{scene}", "joint", "{method}"),
    benchmark:
        LAYOUT.benchmark("{scene}", "joint", "{method}"),
    threads: all_cores()
    resources:
        **device_resources(lambda wc: METHOD[wc.method].device),
    conda:
        CONDA_ENV
    shell:
        "OMP_NUM_THREADS={threads} {EVE3D} joint --method {wildcards.method} --scene {input.scene}"
        " --out {params.out} {params.priors} --config {params.config} > {log} 2>&1"
