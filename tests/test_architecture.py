"""The import rule of docs/architecture.md: stages use the library, never each other; the
library never imports a stage, the front (``cli``, ``config``) or the tools; the core imports
only itself."""
import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent.parent / "eve3d"
STAGES = {"synth", "sfm", "pretrain", "stereo", "joint", "mesh", "evaluate", "report"}
FRONT = {"cli", "config", "__main__"}
LIBRARY = {"core": {"core"}, "gaussians": {"core", "gaussians"}, "priors": {"core", "gaussians", "priors"}}
"""Each library package and what it may import."""
TOOLS = {"tools"}


def part(path: Path) -> str:
    """The top-level part of the package that ``path`` belongs to (``core``, ``joint``, …)."""
    return path.relative_to(PACKAGE).parts[0].removesuffix(".py")


def imported_parts(path: Path) -> set[str]:
    """The top-level parts of ``eve3d`` that the module at ``path`` imports, at any depth."""
    parts = set()
    for node in ast.walk(ast.parse(path.read_text())):
        names = []
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names = [node.module] if node.module != "eve3d" else [f"eve3d.{a.name}" for a in node.names]
        elif isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        parts |= {name.split(".")[1] for name in names if name.startswith("eve3d.")}
    return parts


def test_every_part_of_the_package_is_placed():
    placed = STAGES | FRONT | set(LIBRARY) | TOOLS | {"__init__"}
    assert {part(p) for p in PACKAGE.rglob("*.py")} <= placed


def test_stages_use_the_library_and_never_each_other():
    wrong = {}
    for path in PACKAGE.rglob("*.py"):
        own = part(path)
        used = imported_parts(path) - {own}
        if own in STAGES:
            bad = used - set(LIBRARY)
        elif own in LIBRARY:
            bad = used - LIBRARY[own]
        else:
            continue
        if bad:
            wrong[str(path.relative_to(PACKAGE))] = sorted(bad)
    assert not wrong, f"imports against the rule (module: what it may not import): {wrong}"
