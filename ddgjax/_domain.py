"""`Domain`: the abstract base of what ddgjax computes on (`Curve`, `Mesh`, `TetMesh`, `MeshBatch`).

The bottom layer knows no domain type (DESIGN.md, layout): `ddgjax._compile.kernel` checks a kernel's
first argument by `isinstance(argument, Domain)` and the hooks below, and a new kind of domain
subclasses `Domain` in its own package without editing this layer. A subclass says which first
parameter name its kernels use (`parameter_name = "mesh"`), how to build one (`how_to_build`, for the
error a wrong argument gets), and what a compiled kernel traces (`for_kernel`: its arrays without the
host-side topology, after the checks an operation declares).
"""

from __future__ import annotations

import threading
import weakref
from collections.abc import Callable
from typing import Any, ClassVar, TypeVar

import equinox as eqx

from ._errors import DDGInputError

_DomainT = TypeVar("_DomainT", bound="Domain")

#: The domain class each kernel first-parameter name stands for, filled as subclasses are defined.
_BY_PARAMETER: dict[str, type[Domain]] = {}

#: Host facts measured once per domain object (`Domain.host_fact`), keyed by the object's id and the fact's
#: name; an entry leaves with its object (`weakref.finalize`).
_HOST_FACTS: dict[tuple[int, str], Any] = {}
_HOST_FACTS_LOCK = threading.Lock()


class Domain(eqx.Module):
    """What ddgjax computes on: an immutable pytree of arrays, with host-side checks and topology hooks.

    Subclasses set `parameter_name` (the first parameter of their kernels, e.g. `"mesh"`) and may
    override `how_to_build` and `for_kernel`.
    """

    #: The name of a kernel's first parameter that stands for this kind of domain (None: not checked by name).
    parameter_name: ClassVar[str | None] = None

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        name = cls.__dict__.get("parameter_name")
        if name is not None:
            _BY_PARAMETER[name] = cls

    @classmethod
    def how_to_build(cls, value: object) -> str:
        """A hint saying how to make this kind of domain, for a `value` that is not one."""
        return f"build one with ddgjax's {cls.__name__} constructors"

    @classmethod
    def require(cls: type[_DomainT], name: str, value: object) -> _DomainT:
        """`value` if it is an instance of this class, else `DDGInputError` naming the argument and how to make one."""
        if isinstance(value, cls):
            return value
        shape = getattr(value, "shape", None)
        given = f"an array of shape {tuple(shape)}" if shape is not None else f"a {type(value).__name__}"
        raise DDGInputError(f"{name}: expected a ddgjax {cls.__name__}, got {given}; {cls.how_to_build(value)}")

    def host_fact(self, name: str, measure: Callable[[], Any]) -> Any:
        """`measure()`, computed once per domain object and kept beside it (its degenerate cells, measured on
        the host at its positions: a domain's arrays never change, `with_vertices` makes a new object).

        Kept outside the object: equinox flattens an instance's extra attributes into its pytree structure,
        so a fact stored on the object would change its treedef and make every `jit` taking it retrace.
        """
        key = (id(self), name)
        with _HOST_FACTS_LOCK:
            if key in _HOST_FACTS:
                return _HOST_FACTS[key]
        value = measure()
        with _HOST_FACTS_LOCK:
            if key not in _HOST_FACTS:
                _HOST_FACTS[key] = value
                weakref.finalize(self, _forget, key)
            return _HOST_FACTS[key]

    def for_kernel(self: _DomainT, operation: str | None) -> _DomainT:
        """What a compiled kernel traces: the arrays without host-only data, after the checks `operation` needs.

        `operation` names an operation that needs a consistently oriented domain (for the error), or is None.
        """
        return self


def _forget(key: tuple[int, str]) -> None:
    with _HOST_FACTS_LOCK:
        _HOST_FACTS.pop(key, None)


def domain_for_parameter(name: str | None) -> type[Domain] | None:
    """The domain class a kernel's first parameter `name` stands for (`"mesh"` -> `Mesh`), or None."""
    return _BY_PARAMETER.get(name) if name is not None else None
