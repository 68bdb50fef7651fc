"""The arrows that must never exist (docs/architecture.md), checked on the source tree.

* ``mapping`` never imports ``localization`` or ``service``; ``localization`` never imports
  ``service``.
* A private module (``pkg/_name.py``) is imported only by modules inside ``pkg``; production
  code never imports a private name (``_x``) from another package.
* Every public name has one import path: a package's ``__init__`` exports only names defined
  inside that package, and no non-``__init__`` module re-exports what it imported.
* No module under ``mapping`` or ``localization`` parses argv, prints, plots or knows HTTP.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("mapping", "localization", "service")


def _modules() -> dict[str, tuple[Path, ast.Module]]:
    out = {}
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            parts = list(path.relative_to(ROOT).with_suffix("").parts)
            is_pkg = parts[-1] == "__init__"
            name = ".".join(parts[:-1] if is_pkg else parts)
            out[name] = (path, ast.parse(path.read_text(encoding="utf-8")))
    return out


MODULES = _modules()


def _package_of(module: str) -> str:
    path, _ = MODULES[module]
    return module if path.name == "__init__.py" else module.rsplit(".", 1)[0]


def _imports(tree: ast.Module) -> list[tuple[str, str | None, int]]:
    """(module, name or None, line) of every absolute import of our packages."""
    found: list[tuple[str, str | None, int]] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            if node.module.split(".")[0] in PACKAGES:
                found += [(node.module, a.name, node.lineno) for a in node.names]
        elif isinstance(node, ast.Import):
            found += [(a.name, None, node.lineno) for a in node.names
                      if a.name.split(".")[0] in PACKAGES]
    return found


def _target(module: str, name: str | None) -> str:
    """The module an import loads: ``from pkg import mod`` loads ``pkg.mod``."""
    if name is not None and f"{module}.{name}" in MODULES:
        return f"{module}.{name}"
    return module


def _private_owner(module: str) -> str | None:
    """The package that owns ``module`` privately, or None if every part is public."""
    parts = module.split(".")
    for i, part in enumerate(parts):
        if part.startswith("_") and not part.startswith("__"):
            return ".".join(parts[:i])
    return None


@pytest.mark.parametrize(("low", "high"), [("mapping", "localization"), ("mapping", "service"),
                                           ("localization", "service")])
def test_lower_layers_never_import_higher_ones(low: str, high: str) -> None:
    bad = [f"{m}:{line} imports {imp}" for m, (_, tree) in MODULES.items()
           if m.split(".")[0] == low for imp, _, line in _imports(tree)
           if imp.split(".")[0] == high]
    assert not bad, bad


def test_private_modules_and_names_stay_inside_their_package() -> None:
    bad = []
    for m, (_, tree) in MODULES.items():
        for imp, name, line in _imports(tree):
            target = _target(imp, name)
            owner = _private_owner(target)
            if owner is not None and not (m == owner or m.startswith(owner + ".")):
                bad.append(f"{m}:{line} imports private module {target}")
            if (name is not None and name.startswith("_") and target == imp
                    and not (m.startswith(_package_of(imp) + ".") or m == _package_of(imp))):
                bad.append(f"{m}:{line} imports private name {imp}.{name}")
    assert not bad, bad


def _defined(tree: ast.Module) -> set[str]:
    names: set[str] = set()
    for node in tree.body:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            names.add(node.name)
        elif isinstance(node, ast.Assign):
            names |= {t.id for t in node.targets if isinstance(t, ast.Name)}
        elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            names.add(node.target.id)
    return names


def _exported(tree: ast.Module) -> list[str]:
    for node in tree.body:
        if isinstance(node, ast.Assign) and any(
                isinstance(t, ast.Name) and t.id == "__all__" for t in node.targets):
            assert isinstance(node.value, (ast.List, ast.Tuple))
            return [str(e.value) for e in node.value.elts if isinstance(e, ast.Constant)]
    return []


def test_every_public_name_has_one_import_path() -> None:
    """``__all__`` of a package lists only names defined in that package (its private
    modules or itself); a plain module's ``__all__`` lists only what it defines."""
    bad = []
    for m, (path, tree) in MODULES.items():
        exported = _exported(tree)
        if not exported:
            continue
        if path.name != "__init__.py":
            bad += [f"{m} re-exports {n}" for n in exported if n not in _defined(tree)]
            continue
        sources = {a.asname or a.name: node.module for node in tree.body
                   if isinstance(node, ast.ImportFrom) and node.module for a in node.names}
        for n in exported:
            src = sources.get(n)
            if n in _defined(tree):
                continue
            if src is None or _private_owner(src) != m:
                bad.append(f"{m} exports {n} from {src} (not a private module of {m})")
    assert not bad, bad


@pytest.mark.parametrize("layer", ["mapping", "localization"])
def test_core_never_prints_parses_argv_plots_or_knows_http(layer: str) -> None:
    forbidden = {"argparse", "matplotlib", "fastapi", "starlette", "httpx", "uvicorn"}
    bad = []
    for m, (_, tree) in MODULES.items():
        if m.split(".")[0] != layer:
            continue
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                bad += [f"{m} imports {a.name}" for a in node.names
                        if a.name.split(".")[0] in forbidden]
            elif isinstance(node, ast.ImportFrom) and node.module:
                if node.module.split(".")[0] in forbidden:
                    bad.append(f"{m} imports {node.module}")
            elif (isinstance(node, ast.Call) and isinstance(node.func, ast.Name)
                  and node.func.id == "print"):
                bad.append(f"{m}:{node.lineno} prints")
    assert not bad, bad
