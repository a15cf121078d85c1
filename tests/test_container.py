"""The Dockerfile installs the way the README does, for the image deploy/kuberay.yaml runs.

No container engine runs here, so the Dockerfile is read, not built: its base image has a Python
the project accepts, it installs the EGL packages CI installs, torch from PyTorch's CPU index
within pyproject's bounds, then the project with `pip install -e .` at the manifest's working
directory, sets MUJOCO_GL=egl, and the tag it is built under is the manifest's image."""

from __future__ import annotations

import re
import shlex
import tomllib
from pathlib import Path

import yaml
from packaging.requirements import Requirement
from packaging.specifiers import SpecifierSet
from packaging.version import Version

ROOT = Path(__file__).resolve().parents[1]
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
CPU_INDEX = "https://download.pytorch.org/whl/cpu"


def instructions(text: str) -> list[tuple[str, str]]:
    """`(INSTRUCTION, arguments)` pairs of a Dockerfile, continuation lines joined, comments out."""
    lines = [line for line in text.splitlines() if not line.lstrip().startswith("#")]
    joined = re.sub(r"\\\n", " ", "\n".join(lines))
    out = []
    for line in joined.splitlines():
        if line.strip():
            word, _, rest = line.strip().partition(" ")
            out.append((word.upper(), " ".join(rest.split())))
    return out


DOCKERFILE = (ROOT / "Dockerfile").read_text()
STEPS = instructions(DOCKERFILE)


def runs() -> list[list[str]]:
    """The shell commands of every RUN, split at `&&`, as argument lists."""
    commands = []
    for word, rest in STEPS:
        if word == "RUN":
            commands += [shlex.split(part) for part in rest.split("&&")]
    return commands


def requirement(name: str) -> Requirement:
    return next(r for r in map(Requirement, PYPROJECT["dependencies"]) if r.name == name)


def test_base_image_has_a_python_the_project_accepts() -> None:
    base = [rest for word, rest in STEPS if word == "FROM"]
    assert len(base) == 1, "one stage"
    match = re.fullmatch(r"python:(\d+\.\d+)[\w.-]*", base[0])
    assert match, f"the base image {base[0]} is an official python image"
    assert Version(match.group(1)) in SpecifierSet(PYPROJECT["requires-python"])


def test_the_egl_packages_ci_installs() -> None:
    ci = (ROOT / ".ci/run").read_text()
    ci_packages = set(re.search(r"apt-get install -y -qq ([^>\n]+)", ci).group(1).split())
    egl = {p for p in ci_packages if p.startswith("lib")}  # the rest (chromium) is the studio test's browser
    assert egl == {"libegl1", "libegl-mesa0", "libgl1", "libgl1-mesa-dri"}
    installed = set()
    for cmd in runs():
        if cmd[:2] == ["apt-get", "install"]:
            installed |= {word for word in cmd[2:] if not word.startswith("-")}
    assert egl <= installed, f"missing {sorted(egl - installed)}"
    assert ("ENV", "MUJOCO_GL=egl") in STEPS or any(word == "ENV" and "MUJOCO_GL=egl" in rest.split() for word, rest in STEPS)


def test_torch_from_the_cpu_index_then_the_project_as_the_readme_installs_it() -> None:
    pips = [cmd[2:] for cmd in runs() if cmd[:2] == ["pip", "install"]]
    torch = [args for args in pips if any(a.startswith("torch") for a in args)]
    assert len(torch) == 1, "torch installed once"
    args = torch[0]
    assert args[args.index("--index-url") + 1] == CPU_INDEX
    spec = Requirement(next(a for a in args if a.startswith("torch")))
    assert spec.specifier == requirement("torch").specifier, "the same bounds as pyproject.toml"
    readme = " ".join((ROOT / "README.md").read_text().split())
    told = re.findall(r'pip install "(torch[^"]*)" --index-url (\S+?)`', readme)
    assert [(Requirement(r).specifier, url) for r, url in told] == [(spec.specifier, CPU_INDEX)], told
    assert ["-e", "."] in pips, "the README's `pip install -e .`"
    assert pips.index(["-e", "."]) > pips.index(args), "torch first, so pip keeps the CPU build"


def test_the_tag_is_the_manifests_image() -> None:
    manifest = yaml.safe_load((ROOT / "deploy/kuberay.yaml").read_text())
    pods = [manifest["spec"]["headGroupSpec"]] + manifest["spec"]["workerGroupSpecs"]
    containers = [c for pod in pods for c in pod["template"]["spec"]["containers"]]
    images = {c["image"] for c in containers}
    assert len(images) == 1, f"one image for head and workers: {images}"
    image = images.pop()
    assert image.rsplit(":", 1)[1] == PYPROJECT["version"], "the image is tagged with the project's version"
    workdir = [rest for word, rest in STEPS if word == "WORKDIR"]
    assert all(c["workingDir"] == workdir[-1] for c in containers), "the pods start where the project is installed"
    for doc in (DOCKERFILE, (ROOT / "deploy/README.md").read_text(), (ROOT / "deploy/kuberay.yaml").read_text()):
        built = re.findall(r"docker build -t (\S+) \.", doc)
        pushed = re.findall(r"docker push (\S+)", doc)
        assert built and set(built) == set(pushed) == {image}
