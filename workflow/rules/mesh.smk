# TSDF fusion of a method's depth maps.


rule mesh:
    input:
        scene=posed_dataset,
        depth=depth_source,
    output:
        LAYOUT.mesh("{scene}", "{method}"),
    params:
        args=mesh_args,
    log:
        LAYOUT.log("{scene}", "mesh", "{method}"),
    benchmark:
        LAYOUT.benchmark("{scene}", "mesh", "{method}"),
    priority: after_training
    conda:
        CONDA_ENV
    shell:
        "{EVE3D} mesh --scene {input.scene} --depth {input.depth} --out {output} {params.args} > {log} 2>&1"
