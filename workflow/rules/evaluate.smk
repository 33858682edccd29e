# Metrics per scene and method, and the summary table over all of them.


rule evaluate:
    input:
        unpack(evaluate_inputs),
    output:
        LAYOUT.metrics("{scene}", "{method}"),
    params:
        args=evaluate_args,
    log:
        LAYOUT.log("{scene}", "evaluate", "{method}"),
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
    conda:
        CONDA_ENV
    shell:
        "{EVE3D} summary {input.metrics} {input.novel_views} --out {output}"
