# Gaussian training: the pretrain stage and the joint stage of each trained method (OpenMP in
# the CPU rasteriser; on a GPU the cores matter less). The chain pretrain → stereo → a method
# with priors is the longest, so its jobs start first: the pretrain on every core, before any
# job that would fit beside it; the stereo jobs next (priority 2), then the joint stages (1),
# each on its share of the cores (training_threads), with the meshes and scores after.


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
    threads: all_cores()
    # Snakemake sums the priorities of the jobs it starts together: 10 outweighs any two
    # others (stereo 2, joint 1), which would otherwise take the cores first
    priority: 10
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
        # not in the command: Snakemake reruns a job whose params change, so a new release's
        # settings for a registered method (eve3d.core.methods) rerun that method's jobs
        method_settings=lambda wc: METHOD[wc.method].settings,
    log:
        LAYOUT.log("{scene}", "joint", "{method}"),
    benchmark:
        LAYOUT.benchmark("{scene}", "joint", "{method}"),
    threads: training_threads()
    priority: 1
    resources:
        **device_resources(lambda wc: METHOD[wc.method].device),
    conda:
        CONDA_ENV
    shell:
        "OMP_NUM_THREADS={threads} {EVE3D} joint --method {wildcards.method} --scene {input.scene}"
        " --out {params.out} {params.priors} --config {params.config} > {log} 2>&1"
