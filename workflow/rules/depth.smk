# Depth priors per view. Backends so far: oracle (exact depth of a scene with a GT mesh).


rule stereo_depth:
    input:
        scene=posed_dataset,
        gt=gt_input,
    output:
        directory(f"{RESULTS}/{{scene}}/priors/{{backend}}"),
    wildcard_constraints:
        backend="oracle",
    params:
        gt=gt_mesh,
    log:
        f"{RESULTS}/logs/{{scene}}/stereo_depth_{{backend}}.log",
    conda:
        CONDA_ENV
    shell:
        "{EVE3D} stereo-depth --backend {wildcards.backend} --scene {input.scene} --gt-mesh {params.gt}"
        " --out {output} > {log} 2>&1"
