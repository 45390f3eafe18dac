"""The Docker image and the native install stay in step, read from the files alone (no Docker
engine, no network): same DOLFINx release, same pins for everything else, a default command that
runs a demo that exists, and every third-party import of the code declared somewhere."""

from __future__ import annotations

import ast
import importlib.metadata
import json
import re
import shlex
import sys
import sysconfig
import tomllib
from pathlib import Path, PurePosixPath

import pytest
from packaging.requirements import Requirement
from packaging.utils import canonicalize_name
from packaging.version import Version

ROOT = Path(__file__).parents[1]
DOCKERFILE = ROOT / "Dockerfile"
INSTALL_SCRIPT = ROOT / "scripts" / "install.sh"
MAKEFILE = ROOT / "Makefile"

# The wheel that brings DOLFINx (with PETSc, MPI, basix, ffcx, ufl) to the native install; in
# Docker the official DOLFINx image brings all of it instead.
DOLFINX_WHEEL = "dolfinx-solver-real"
OFFICIAL_IMAGES = ("dolfinx/dolfinx", "docker.io/dolfinx/dolfinx", "ghcr.io/fenics/dolfinx/dolfinx")
# Modules that come with DOLFINx: natively as the dolfinx-solver-real wheel and its own
# dependencies, in Docker from the image. Nothing else may be imported without being pinned.
DOLFINX_STACK = {"dolfinx", "basix", "ffcx", "ufl", "mpi4py", "petsc4py", "slepc4py", "numpy"}
# Import name -> distribution name, where they differ (add an entry with a new such dependency).
DISTRIBUTION_OF = {"yaml": "pyyaml", "PIL": "pillow", "skimage": "scikit-image"}
SCANNED = ("fenics_adaptive", "meshes", "demos")


# ------------------------------------------------------------------ reading the files
def dockerfile_instructions() -> list[tuple[str, str]]:
    """(INSTRUCTION, arguments) of the Dockerfile, continuation lines joined, comments dropped."""
    instructions, pending = [], ""
    for raw in DOCKERFILE.read_text().splitlines():
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        if line.endswith("\\"):
            pending += line[:-1] + " "
            continue
        line, pending = pending + line, ""
        keyword, _, rest = line.partition(" ")
        instructions.append((keyword.upper(), rest.strip()))
    assert not pending, "the Dockerfile ends inside a continued line"
    return instructions


def expand_args(text: str, args: dict[str, str]) -> str:
    return re.sub(
        r"\$\{(\w+)\}|\$(\w+)", lambda m: args.get(m.group(1) or m.group(2), m.group(0)), text
    )


def base_image() -> str:
    """The image of the last FROM (the stage the image is built from), ARGs expanded."""
    args, image = {}, None
    for keyword, rest in dockerfile_instructions():
        if keyword == "ARG" and "=" in rest:
            name, _, value = rest.partition("=")
            args[name.strip()] = value.strip().strip('"')
        elif keyword == "FROM":
            words = [w for w in rest.split() if not w.startswith("--")]
            image = expand_args(words[0], args)
    assert image is not None, "the Dockerfile has no FROM"
    return image


def split_image(image: str) -> tuple[str, str]:
    """(repository, tag) of ``repo[:tag][@digest]``."""
    name = image.split("@")[0]
    repository, _, tag = name.rpartition(":") if ":" in name.split("/")[-1] else (name, "", "")
    return repository, tag


def requirement_lines(path: Path) -> list[str]:
    lines = []
    for raw in path.read_text().splitlines():
        line = raw.split("#", 1)[0].strip()
        if line:
            lines.append(line)
    return lines


def requirement_files(path: Path) -> list[Path]:
    """The file and every file it includes with ``-r``, depth first."""
    assert path.is_file(), f"requirements file {path.relative_to(ROOT)} is missing"
    files = [path]
    for line in requirement_lines(path):
        if line.startswith(("-r ", "--requirement ")):
            files += requirement_files(path.parent / line.split(None, 1)[1])
    return files


def pins(files: list[Path]) -> dict[str, Requirement]:
    """Canonical distribution name -> requirement, over the files (``-r`` lines skipped)."""
    out = {}
    for path in files:
        for line in requirement_lines(path):
            if line.startswith("-"):
                continue
            requirement = Requirement(line)
            out[canonicalize_name(requirement.name)] = requirement
    return out


def install_script_requirement_files() -> list[Path]:
    """Requirement files scripts/install.sh installs with ``pip install -r``, includes followed."""
    text = INSTALL_SCRIPT.read_text()
    named = re.findall(r"pip install[^\n]*?-r\s+\"?\$root/([\w./-]+)\"?", text)
    assert named, "scripts/install.sh installs no requirements file with -r"
    return [f for name in named for f in requirement_files(ROOT / name)]


def docker_requirement_files() -> list[Path]:
    """Requirement files the Dockerfile installs with ``pip install -r``, relative to the folder
    the build context is copied to (includes followed)."""
    files = []
    for keyword, rest in dockerfile_instructions():
        if keyword == "RUN" and "pip install" in rest:
            words = shlex.split(rest)
            files += [
                ROOT / words[k + 1].rstrip(";")  # a shell command may end at the file
                for k, w in enumerate(words[:-1])
                if w in ("-r", "--requirement")
            ]
    return [f for path in files for f in requirement_files(path)]


def docker_command() -> list[str]:
    commands = [rest for keyword, rest in dockerfile_instructions() if keyword == "CMD"]
    assert commands, "the Dockerfile has no CMD"
    command = commands[-1]
    return json.loads(command) if command.startswith("[") else shlex.split(command)


def build_context_folder() -> PurePosixPath:
    """Where ``COPY . <dest>`` puts the repository in the image (relative dest: to WORKDIR)."""
    workdir = PurePosixPath("/")
    for keyword, rest in dockerfile_instructions():
        if keyword == "WORKDIR":
            workdir = workdir / rest
        elif keyword == "COPY":
            words = [w for w in rest.split() if not w.startswith("--")]
            if words[:-1] == ["."]:
                return workdir / words[-1]
    raise AssertionError("the Dockerfile does not copy the repository (COPY . <folder>)")


def makefile_demo_script() -> str:
    """The script ``make demo`` runs."""
    text = MAKEFILE.read_text()
    recipe = re.search(r"^demo:.*\n((?:\t.*\n?)+)", text, re.MULTILINE)
    assert recipe, "the Makefile has no demo target"
    scripts = re.findall(r"(demos/\S+\.py)", recipe.group(1))
    assert scripts, "make demo runs no demos/*.py"
    return scripts[0]


# ------------------------------------------------------------------ (a) same DOLFINx
def test_docker_base_image_is_the_official_dolfinx_image_of_the_native_release():
    repository, tag = split_image(base_image())
    assert repository in OFFICIAL_IMAGES, f"base image {repository!r} is not the official DOLFINx"
    match = re.fullmatch(r"v(\d+\.\d+\.\d+)(-r\d+)?", tag)
    assert match, f"base image tag {tag!r} is not a DOLFINx release tag such as v0.11.0"
    native = pins(install_script_requirement_files())
    assert DOLFINX_WHEEL in native, f"the native install pins no {DOLFINX_WHEEL}"
    specifiers = list(native[DOLFINX_WHEEL].specifier)
    assert len(specifiers) == 1 and specifiers[0].operator == "==", (
        f"{DOLFINX_WHEEL} is not pinned exactly: {native[DOLFINX_WHEEL]}"
    )
    native_release = Version(specifiers[0].version).release  # 0.11.0.post0 -> (0, 11, 0)
    image_release = Version(match.group(1)).release
    assert image_release == native_release, (
        f"Docker uses DOLFINx {match.group(1)}, the native install "
        f"{DOLFINX_WHEEL} {specifiers[0].version}"
    )


# ------------------------------------------------------------------ (b) same pins
def test_docker_installs_the_pins_the_install_script_uses():
    native_files = install_script_requirement_files()
    docker_files = docker_requirement_files()
    assert docker_files, "the Dockerfile installs no requirements file"
    for path in docker_files:
        assert path in native_files, (
            f"the Dockerfile installs {path.relative_to(ROOT)}, which scripts/install.sh does "
            f"not use ({[str(f.relative_to(ROOT)) for f in native_files]})"
        )
    native, docker = pins(native_files), pins(docker_files)
    assert DOLFINX_WHEEL not in docker, "the image brings DOLFINx: do not install the wheel too"
    assert set(docker) == set(native) - {DOLFINX_WHEEL}, (
        "the image and the native install must get the same non-DOLFINx pins: only in native "
        f"{sorted(set(native) - set(docker) - {DOLFINX_WHEEL})}, only in Docker "
        f"{sorted(set(docker) - set(native))}"
    )
    for name, requirement in native.items():
        operators = [s.operator for s in requirement.specifier]
        assert operators == ["=="], f"{requirement} is not pinned exactly (name==version)"
        assert docker.get(name, requirement) == requirement


def test_requirement_files_are_copied_before_they_are_installed():
    copied = []
    for keyword, rest in dockerfile_instructions():
        if keyword == "COPY":
            words = [w for w in rest.split() if not w.startswith("--")]
            copied += [w.rstrip("/") for w in words[:-1]]
        elif keyword == "RUN" and "pip install" in rest:
            words = shlex.split(rest)
            for k, w in enumerate(words[:-1]):
                if w in ("-r", "--requirement"):
                    path = words[k + 1].rstrip(";")
                    assert any(c == "." or path == c or path.startswith(c + "/") for c in copied), (
                        f"RUN installs {path} before any COPY brings it into the image"
                    )


# ------------------------------------------------------------------ (c) the default command
def test_docker_default_command_runs_the_main_demo_into_results():
    command = docker_command()
    scripts = [w for w in command if w.endswith(".py")]
    assert scripts, f"the default command {command} runs no Python script"
    script = PurePosixPath(scripts[0])
    context = build_context_folder()
    if script.is_absolute():
        assert script.is_relative_to(context), f"{script} is not in the copied repository"
        script = script.relative_to(context)
    assert (ROOT / script).is_file(), f"the default command runs {script}, which does not exist"
    assert str(script) == makefile_demo_script(), "Docker and `make demo` run different demos"
    assert "--out" in command, "the default command does not say where the results go"
    out = PurePosixPath(command[command.index("--out") + 1])
    assert out.is_relative_to("/results"), f"results go to {out}, not into /results (mounted)"


# ------------------------------------------------------------------ (d) declared imports
def imported_modules(path: Path) -> set[str]:
    """Top-level names of the absolute imports of a file."""
    tree = ast.parse(path.read_text(), filename=str(path))
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(alias.name.split(".")[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module.split(".")[0])
    return names


def declared_distributions() -> set[str]:
    pyproject = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    declared = [Requirement(r).name for r in pyproject.get("dependencies", [])]
    for extra in pyproject.get("optional-dependencies", {}).values():
        declared += [Requirement(r).name for r in extra]
    declared += list(pins(install_script_requirement_files()))
    return {canonicalize_name(name) for name in declared}


def test_every_imported_dependency_is_declared():
    pyproject = tomllib.loads((ROOT / "pyproject.toml").read_text())
    project = set(pyproject["tool"]["setuptools"]["packages"])
    declared = declared_distributions()
    assert canonicalize_name(DOLFINX_WHEEL) in declared
    missing = {}
    for folder in SCANNED:
        for path in sorted((ROOT / folder).rglob("*.py")):
            for module in imported_modules(path):
                if (
                    module in sys.stdlib_module_names
                    or module == "__future__"
                    or module in project
                    or module in DOLFINX_STACK
                    or canonicalize_name(DISTRIBUTION_OF.get(module, module)) in declared
                ):
                    continue
                missing.setdefault(module, []).append(str(path.relative_to(ROOT)))
    assert not missing, (
        "imported but neither stdlib, the project, DOLFINx's stack, nor pinned in "
        f"requirements/common.txt: {missing}"
    )


def test_import_scan_sees_the_dependencies():
    """Guards the scan itself: it must find the known third-party imports."""
    found = set().union(
        *(imported_modules(p) for folder in SCANNED for p in (ROOT / folder).rglob("*.py"))
    )
    assert {"dolfinx", "numba", "gmsh", "matplotlib", "numpy", "fenics_adaptive"} <= found


def test_dolfinx_stack_comes_with_the_native_wheel():
    """Natively, the DOLFINX_STACK modules must be brought by the pinned wheel (checked against
    its installed metadata where it is installed; the Docker image has its own DOLFINx)."""
    metadata = importlib.metadata
    try:
        requires = metadata.requires(DOLFINX_WHEEL) or []
    except metadata.PackageNotFoundError:
        pytest.skip(f"{DOLFINX_WHEEL} is not installed here (the Docker image)")
    brought = {canonicalize_name(Requirement(r).name) for r in requires if "extra" not in r}
    providers = metadata.packages_distributions()
    for module in DOLFINX_STACK:
        dists = {canonicalize_name(d) for d in providers.get(module, [])}
        if not dists:
            continue  # not installed natively (e.g. slepc4py in some wheels)
        assert dists & (brought | {canonicalize_name(DOLFINX_WHEEL)}), (
            f"{module} ({dists}) is not brought by {DOLFINX_WHEEL}: pin it in requirements/"
        )


# ------------------------------------------------------------------ (e) repository habits
PYPROJECT = ROOT / "pyproject.toml"
PACKAGE = ROOT / "fenics_adaptive"
# The first line of the license text of each SPDX identifier the project may declare.
LICENSE_TITLES = {"MIT": "MIT License"}
KEEP_A_CHANGELOG_KINDS = {"Added", "Changed", "Deprecated", "Removed", "Fixed", "Security"}
PYTEST_BUILTIN_MARKERS = {"parametrize", "skip", "skipif", "xfail", "usefixtures", "filterwarnings"}


def pyproject() -> dict:
    return tomllib.loads(PYPROJECT.read_text())


def package_version() -> str:
    """The literal ``__version__`` of fenics_adaptive/__init__.py, read without importing it."""
    tree = ast.parse((PACKAGE / "__init__.py").read_text())
    for node in tree.body:
        if isinstance(node, ast.Assign) and [getattr(t, "id", None) for t in node.targets] == [
            "__version__"
        ]:
            assert isinstance(node.value, ast.Constant), "__version__ must be a string literal"
            return node.value.value
    raise AssertionError("fenics_adaptive/__init__.py assigns no __version__")


def test_license_file_matches_the_declared_license():
    project = pyproject()["project"]
    license = project["license"]
    assert isinstance(license, str), "license is an SPDX expression (PEP 639), not a table"
    assert license in LICENSE_TITLES, f"no known license text for {license!r}"
    assert project.get("license-files") == ["LICENSE"]
    text = (ROOT / "LICENSE").read_text()
    assert text.splitlines()[0].strip() == LICENSE_TITLES[license]
    assert re.search(r"Copyright \(c\) \d{4} \S", text), "the LICENSE names no copyright holder"


def test_the_version_has_one_source():
    data = pyproject()
    assert "version" not in data["project"], "pyproject.toml must not repeat the version"
    assert "version" in data["project"].get("dynamic", [])
    attr = data["tool"]["setuptools"]["dynamic"]["version"]["attr"]
    assert attr == "fenics_adaptive.__version__"
    version = Version(package_version())  # a valid PEP 440 version
    literal = re.compile(rf"""["']v?{re.escape(str(version))}["']""")
    copies = []
    for folder in ("fenics_adaptive", "meshes", "demos", "docs", "tests", "benchmarks", "scripts"):
        for path in sorted((ROOT / folder).rglob("*")):
            if path.suffix in (".py", ".toml", ".cfg", ".sh", ".md", ".txt") and path.is_file():
                if path != PACKAGE / "__init__.py" and literal.search(path.read_text()):
                    copies.append(str(path.relative_to(ROOT)))
    for name in ("Dockerfile", "Makefile", "pyproject.toml", "README.md"):
        if literal.search((ROOT / name).read_text()):
            copies.append(name)
    assert not copies, f"the version {version} is written out in {copies}: read __version__"


def test_the_command_line_reports_the_version(capsys):
    from fenics_adaptive import __version__, cli

    with pytest.raises(SystemExit) as stop:
        cli.main(["--version"])
    assert stop.value.code == 0
    assert capsys.readouterr().out.split() == ["fenics-adaptive", __version__]
    assert __version__ == package_version()


def test_the_package_ships_its_type_hints():
    assert (PACKAGE / "py.typed").is_file()
    package_data = pyproject()["tool"]["setuptools"]["package-data"]
    assert "py.typed" in package_data.get("fenics_adaptive", [])


def test_the_changelog_keeps_a_changelog():
    text = (ROOT / "CHANGELOG.md").read_text()
    lines = text.splitlines()
    assert lines[0] == "# Changelog"
    assert "keepachangelog.com" in text
    releases = re.findall(r"^## \[([^\]]+)\](.*)$", text, re.MULTILINE)
    assert releases and releases[0][0] == "Unreleased", "the first section is [Unreleased]"
    dated = {name: rest for name, rest in releases[1:]}
    for name, rest in dated.items():
        Version(name)
        assert re.fullmatch(r" - \d{4}-\d{2}-\d{2}", rest), f"[{name}] needs ' - YYYY-MM-DD'"
    assert package_version() in dated, "the package's version has no section in CHANGELOG.md"
    kinds = set(re.findall(r"^### (.+)$", text, re.MULTILINE))
    assert kinds and kinds <= KEEP_A_CHANGELOG_KINDS, kinds - KEEP_A_CHANGELOG_KINDS


def test_the_readme_links_license_changelog_and_contributing():
    readme = (ROOT / "README.md").read_text()
    for name in ("LICENSE", "CHANGELOG.md", "CONTRIBUTING.md"):
        assert (ROOT / name).is_file(), name
        assert f"]({name})" in readme, f"README.md does not link {name}"


def test_every_marker_the_tests_use_is_registered():
    options = pyproject()["tool"]["pytest"]["ini_options"]
    assert "--strict-markers" in options["addopts"].split()
    registered = {line.split(":")[0].strip() for line in options["markers"]}
    assert {"slow", "mpi", "docs"} <= registered
    used = set()
    for path in sorted((ROOT / "tests").glob("*.py")):
        used |= set(re.findall(r"pytest\.mark\.(\w+)", path.read_text()))
    used -= PYTEST_BUILTIN_MARKERS
    assert used, "the scan found no marker"
    assert used <= registered, f"markers used but not registered: {sorted(used - registered)}"


# ------------------------------------------------------------------ (f) the lock
LOCK = ROOT / "requirements" / "lock.txt"
# tools of the environment, not dependencies of the project
NOT_LOCKED = {"pip", "fenics-adaptive"}


def lock() -> dict[str, str]:
    """Canonical name -> pinned version of requirements/lock.txt."""
    out = {}
    for line in requirement_lines(LOCK):
        requirement = Requirement(line)
        (specifier,) = requirement.specifier
        assert specifier.operator == "==", f"lock.txt: {line} is not an exact pin"
        name = canonicalize_name(requirement.name)
        assert name not in out, f"lock.txt pins {name} twice"
        out[name] = specifier.version
    return out


def test_the_lock_pins_every_requirement_at_its_version():
    locked = lock()
    files = [*install_script_requirement_files(), *docker_requirement_files()]
    for name, requirement in pins(files).items():
        (specifier,) = requirement.specifier
        assert locked.get(name) == specifier.version, (
            f"{requirement} but lock.txt pins {name}=={locked.get(name)}: run scripts/lock.sh"
        )


def test_the_lock_holds_every_distribution_of_this_install():
    """Where the native install runs these tests, every distribution it holds is locked at
    the version it holds: a fresh install under the lock is this one."""
    try:
        importlib.metadata.version(DOLFINX_WHEEL)
    except importlib.metadata.PackageNotFoundError:
        pytest.skip("not the native install (the Docker image has its own DOLFINx stack)")
    locked = lock()
    # the environment's own site-packages: not the copies setuptools vendors and puts on
    # sys.path once imported (as FFCx's compiler does)
    folders = sorted({sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"]})
    installed = {
        canonicalize_name(d.metadata["Name"]): d.version
        for d in importlib.metadata.distributions(path=folders)
    }
    differ = {
        name: (version, locked.get(name))
        for name, version in installed.items()
        if name not in NOT_LOCKED and locked.get(name) != version
    }
    assert not differ, f"installed vs locked (run scripts/lock.sh): {differ}"


def test_every_pip_install_is_constrained_by_the_lock():
    lines = [
        line for line in INSTALL_SCRIPT.read_text().splitlines() if re.search(r"pip install", line)
    ]
    lines += [rest for keyword, rest in dockerfile_instructions() if keyword == "RUN"]
    requirement_installs = [line for line in lines if re.search(r"pip install[^\n]* -r ", line)]
    assert len(requirement_installs) >= 4
    text = INSTALL_SCRIPT.read_text()
    assert re.search(r'lock=\(-c "\$root/requirements/lock\.txt"\)', text)
    for line in requirement_installs:
        for segment in re.split(r"&&|;", line):
            if "pip install" in segment and " -r " in segment:
                assert "-c requirements/lock.txt" in segment or '"${lock[@]}"' in segment, (
                    f"installs without the lock: {segment.strip()}"
                )


def test_docker_takes_gmsh_from_the_image_or_the_wheel_never_both():
    (run,) = [
        rest for keyword, rest in dockerfile_instructions() if "requirements/gmsh.txt" in rest
    ]
    condition, wheel = run.split("else", 1)
    assert "import gmsh" in condition and "pip install" not in condition
    assert "pip install" in wheel and "libglu1-mesa" in wheel
    common = requirement_lines(ROOT / "requirements" / "common.txt")
    assert not any(canonicalize_name(Requirement(r).name) == "gmsh" for r in common
                   if not r.startswith("-"))  # fmt: skip


def test_the_native_extra_brings_the_pinned_dolfinx_wheel():
    extra = [Requirement(r) for r in pyproject()["project"]["optional-dependencies"]["native"]]
    native = pins([ROOT / "requirements" / "native.txt"])
    assert [canonicalize_name(r.name) for r in extra] == [DOLFINX_WHEEL]
    assert extra[0].specifier == native[DOLFINX_WHEEL].specifier
