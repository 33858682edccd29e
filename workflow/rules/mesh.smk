# TSDF fusion of a method's depth maps.


rule mesh:
    input:
        scene=posed_dataset,
        depth=depth_source,
    output:
        f"{RESULTS}/{{scene}}/{{method}}/mesh.ply",
    params:
        args=mesh_args,
    log:
        f"{RESULTS}/logs/{{scene}}/mesh_{{method}}.log",
    benchmark:
        f"{RESULTS}/benchmarks/{{scene}}/mesh_{{method}}.tsv",
    conda:
        CONDA_ENV
    shell:
        "{EVE3D} mesh --scene {input.scene} --depth {input.depth} --out {output} {params.args} > {log} 2>&1"
