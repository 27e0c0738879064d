"""The Docker image's files agree with the project: the lock pins every dependency within pyproject's ranges, the
docs/deploy.md's Ray version is the lock's, the image runs as a numeric non-root user and gets no git metadata."""

import re
import tomllib
from pathlib import Path

from packaging.requirements import Requirement
from packaging.utils import canonicalize_name
from packaging.version import Version

ROOT = Path(__file__).resolve().parents[1]


def _lock() -> dict[str, Version]:
    pins = {}
    for line in (ROOT / "docker" / "requirements.lock").read_text().splitlines():
        if line.strip() and not line.startswith("#"):
            name, version = line.split("==")
            pins[canonicalize_name(name)] = Version(version)
    return pins


def test_the_lock_pins_every_dependency_within_pyproject_ranges() -> None:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    pins = _lock()
    for spec in [*project["dependencies"], *project["optional-dependencies"]["ray"]]:
        req = Requirement(spec)
        name = canonicalize_name(req.name)
        assert name in pins, f"{req.name} is not pinned in docker/requirements.lock"
        assert req.specifier.contains(pins[name], prereleases=True), f"{req.name} {pins[name]} not in {req.specifier}"
    assert pins["torch"].local == "cpu"  # never the CUDA build


def test_deploy_doc_ray_version_is_the_lock_s_and_the_user_is_numeric() -> None:
    readme = (ROOT / "docs" / "deploy.md").read_text()
    assert re.search(r'rayVersion: "([^"]+)"', readme).group(1) == str(_lock()["ray"])
    dockerfile = (ROOT / "Dockerfile").read_text()
    users = re.findall(r"^USER (\S+)", dockerfile, re.M)
    assert users and all(re.fullmatch(r"\d+(:\d+)?", u) and not u.startswith("0") for u in users)
    assert "ARG GIT_COMMIT" in dockerfile and "BRL_GIT_COMMIT" in dockerfile
    assert not re.search(r"apt-get install[^\n]*\bgit\b", dockerfile)  # the commit comes as a build argument
    ignore = (ROOT / ".dockerignore").read_text().splitlines()
    assert ignore[ignore.index("*") if "*" in ignore else 0] == "*" and "!.git" not in ignore
