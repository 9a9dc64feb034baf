"""The imports run one way: setups → lake, train → lake, never lake → setups, train or metrics."""

from __future__ import annotations

import ast
import os
import re
import subprocess
import sys

from .conftest import ROOT

OUTSIDE_LAKE = ("datagen", "train", "metrics")
OUTSIDE_PATH = re.compile(r"\.\./shared")  # the folder beside a checkout that a user who clones does not have
OUTSIDE_SPEC = re.compile(r"\bSPEC(\.md|\s+\d|\s+§)")  # the specification the project was built from is not shipped


def part(name: str) -> str | None:
    """The part of smspace a module belongs to (smspace.lake.store -> lake), None for others."""
    pieces = name.split(".")
    return pieces[1] if pieces[0] == "smspace" and len(pieces) > 1 else None


def imported_modules(path) -> set[str]:
    tree = ast.parse(path.read_text())
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module)
    return names


# Each package imports only packages of a lower layer: common and the schemas at the bottom, the
# command lines and the Python API (smspace/: cli.py, api.py) at the top, assembling the rest.
LAYERS = {"common": 0, "schemas": 0, "lake": 1, "metrics": 1, "datagen": 2, "train": 2, "study": 3, "bench": 4}
TOP = 5  # smspace/ itself


def imported_parts(path) -> set[str]:
    """The parts of smspace a file imports (`from smspace import schemas` included)."""
    parts = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module == "smspace" and node.level == 0:
            parts.update(alias.name for alias in node.names)
        elif isinstance(node, ast.Import | ast.ImportFrom):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else [node.module or ""]
            if getattr(node, "level", 0) == 0:
                parts.update(p for n in names if (p := part(n)))
    return parts


def test_every_package_imports_only_the_layers_below_it():
    """study/cli.py imported bench.cli at its end to add `smtrain bench` (study -> bench, a layer
    up); the layout test did not cover bench/ at all. smspace/cli.py now groups the commands."""
    offending = []
    for package, layer in [*LAYERS.items(), ("smspace", TOP)]:
        files = sorted((ROOT / package).rglob("*.py"))
        assert files, package
        for path in files:
            for name in imported_parts(path):
                own = name == package or (package == "smspace" and name not in LAYERS)  # smspace.api, .cli
                if not own and LAYERS.get(name, TOP) >= layer:
                    offending.append(f"{path.relative_to(ROOT)} imports smspace.{name}")
    assert not offending, offending


def test_the_lake_imports_nothing_of_the_generators_or_training():
    files = sorted((ROOT / "lake").rglob("*.py"))
    assert len(files) >= 8
    offending = {
        f"{path.relative_to(ROOT)} imports {name}"
        for path in files
        for name in imported_modules(path)
        if part(name) in OUTSIDE_LAKE
    }
    assert not offending, offending


def test_importing_the_whole_lake_loads_no_setup():
    code = (
        "import sys, smspace.lake.catalog, smspace.lake.dataset, smspace.lake.normalise, smspace.lake.shards,"
        " smspace.lake.validate, smspace.lake.transitions;"
        "print(','.join(sorted(m for m in sys.modules if m.split('.')[1:2] in (['datagen'], ['train'], ['metrics']))))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT)
    assert out.stdout.strip() == ""


def test_common_imports_nothing_of_the_project_but_itself():
    for path in sorted((ROOT / "common").rglob("*.py")):
        for name in imported_modules(path):
            assert part(name) not in (*OUTSIDE_LAKE, "lake"), f"{path.relative_to(ROOT)} imports {name}"


def test_nothing_points_outside_the_repository():
    tracked = subprocess.run(["git", "ls-files"], capture_output=True, text=True, cwd=ROOT, check=True).stdout.split()
    texts = {p: (ROOT / p).read_text() for p in tracked if p.endswith((".py", ".md", ".sh", ".toml"))}
    bad = [p for p, text in texts.items() if OUTSIDE_PATH.search(text) or OUTSIDE_SPEC.search(text)]
    assert not bad, bad


def test_training_imports_nothing_of_the_generators():
    """A run needs only the lake: the setup's suggested network travels in the manifest. The one
    command that composes both (`smtrain sweep`) lives above them, in study/cli.py: no exemption."""
    files = sorted((ROOT / "train").rglob("*.py"))
    assert len(files) >= 10
    offending = {
        f"{path.relative_to(ROOT)} imports {name}"
        for path in files
        for name in imported_modules(path)
        if part(name) in ("datagen", "study")
    }
    assert not offending, offending


def test_only_smspace_is_a_top_level_package():
    """Everything imports as smspace.…: a researcher's own train.py or metrics.py shadows nothing."""
    for path in [*ROOT.rglob("*.py")]:
        if {".venv", "examples", "build"} & set(path.parts):
            continue
        for name in imported_modules(path):
            head = name.split(".")[0]
            assert head not in ("common", "lake", "datagen", "train", "metrics", "schemas", "study"), (path, name)


def test_test_modules_share_helpers_through_conftest_not_each_other():
    """A helper one test module needs from another lives in tests/conftest.py (or numerics, servers,
    faults): importing a test module runs its fixtures' module scope and couples two suites."""
    offending = []
    for path in sorted((ROOT / "tests").glob("test_*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[-1].startswith("test_"):
                offending.append(f"{path.name} imports {node.module}")
    assert not offending, offending


def test_the_command_line_starts_without_torch():
    """`smtrain --help`, `--version` and every Tab took 3-4 s: torch was imported to build the flags.
    Counted in modules, not seconds (benchmarks/bench_startup.py measures the time)."""
    probe = (
        "import sys\n"
        "from smspace.cli import smtrain\n"
        "from smspace.cli import smgen\n"
        "for main in (smtrain, smgen):\n"
        "    try:\n"
        "        main(['--help'], standalone_mode=False)\n"
        "    except SystemExit:\n"
        "        pass\n"
        "print(sorted(m for m in sys.modules if m == 'torch' or m.startswith('torch.'))[:3])\n"
    )
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert done.returncode == 0 and done.stdout.strip().splitlines()[-1] == "[]", done.stdout + done.stderr


def test_ls_and_info_read_run_folders_without_torch(tmp_path):
    """`smtrain ls` and `info` took 3 s on a run folder: reading it imported torch (checkpoints)
    and tensorboardX (the event stream). Both are imported where a checkpoint or stream is
    written or loaded; reading a folder needs neither."""
    from .conftest import SAMPLES, smtrain

    runs = tmp_path / "runs"
    done = smtrain("fit", "grid-seed0-MM", "--lake", SAMPLES, "--out", runs / "one", "--steps", 20, "--eval-every", 10)
    assert done.exit_code == 0, done.output
    probe = (
        "import sys\n"
        "from smspace.cli import smtrain as main\n"
        "for args in (['ls', '--runs', sys.argv[1]], ['info', sys.argv[2]]):\n"
        "    try:\n"
        "        main(args, standalone_mode=False)\n"
        "    except SystemExit:\n"
        "        pass\n"
        "print(sorted(m for m in sys.modules if m.split('.')[0] in ('torch', 'tensorboardX'))[:3])\n"
    )
    shown = subprocess.run([sys.executable, "-c", probe, str(runs), str(runs / "one")], capture_output=True,
                           text=True, cwd=ROOT, timeout=120)  # fmt: skip
    assert shown.returncode == 0 and "MM" in shown.stdout, shown.stdout + shown.stderr
    assert shown.stdout.strip().splitlines()[-1] == "[]", shown.stdout


def test_the_engine_imports_no_run_folder_lake_or_launcher():
    """The training engine is read in one pass: what it trains comes in as members, what it makes
    leaves through sinks; run folders, the lake and the launchers are its callers' business."""
    names = imported_modules(ROOT / "train" / "engine.py")
    banned = ("smspace.lake", "smspace.train.run_dir", "smspace.train.fit", "smspace.train.launch",
              "smspace.train.cli", "smspace.train.loader", "smspace.study", "smspace.datagen")  # fmt: skip
    assert not [n for n in names if n.startswith(banned)], names
    fit_imports = imported_modules(ROOT / "train" / "fit.py")
    assert not [n for n in fit_imports if n.startswith(("smspace.train.cli", "smspace.train.launch"))], fit_imports


def test_smtrain_fit_reaches_its_first_step_through_four_modules_of_train(tmp_path, monkeypatch):
    """cli -> fit -> engine -> model, nothing in between, nothing crossing back."""
    import traceback

    from smspace.train import model

    from .conftest import SAMPLES, smtrain

    stacks: list[list[str]] = []
    real_forward = model.SensorimotorNet.forward

    def forward(self, *args):
        frames = traceback.extract_stack()
        if not stacks and any(f.name == "train_step" for f in frames):  # the first optimizer step
            stacks.append([f.filename for f in frames])
        return real_forward(self, *args)

    monkeypatch.setattr(model.SensorimotorNet, "forward", forward)
    out = tmp_path / "run"
    result = smtrain("fit", "grid-seed0-MM", "--lake", SAMPLES, "--out", out, "--steps", 2, "--eval-every", 1)
    assert result.exit_code == 0, result.output
    train_dir = str(ROOT / "train")
    chain = list(dict.fromkeys(os.path.basename(f) for f in stacks[0] if f.startswith(train_dir)))
    assert chain == ["cli.py", "fit.py", "engine.py"], chain  # and then model.py's forward: four modules
    assert real_forward.__module__ == "smspace.train.model"
