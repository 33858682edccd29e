# eve3d workflow: `snakemake -c2` runs every scene of config/config.yaml; see README.md.
configfile: "config/config.yaml"
report: "workflow/report/workflow.rst"


include: "workflow/rules/common.smk"
include: "workflow/rules/data.smk"
include: "workflow/rules/depth.smk"
include: "workflow/rules/train.smk"
include: "workflow/rules/mesh.smk"
include: "workflow/rules/evaluate.smk"


rule all:
    input:
        LAYOUT.summary(),
        mesh_files(),
        LAYOUT.report_pages() / "summary.html",
    default_target: True
