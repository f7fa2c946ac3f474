r"""The C99 emitter: a traced JAX function (its jaxpr) translated into one C function.

Every value of the jaxpr is scalarized: an array of static shape becomes one C variable per
element (a NumPy object array of C expressions stands for it while translating), so the
structural primitives (slices, reshapes, broadcasts, concatenations, transposes) cost nothing
and the arithmetic is a list of `const double t12 = ...;` statements that a C compiler keeps in
registers. Nested jaxprs (`jit`, custom derivatives, checkpoints) are inlined; a `scan` of fixed
length (a `fori_loop` with static bounds: the integrator's sub-steps) becomes a `for` loop and a
`cond` an `if` chain. Statements whose values no output needs are dropped (so the C compiles
without unused-variable warnings).

Only the primitives of :data:`PRIMITIVES` are translated; any other (a `while_loop`, a random
number, a special function without a C99 counterpart, a linear solve) raises
:class:`UnsupportedPrimitive`, one line naming it.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from collections.abc import Callable, Sequence

import jax
import numpy as np
from jax.extend import core

from .._errors import InputError

#: Element-wise primitives and their C99 form (`{0}`, `{1}`: the operands), for floating-point
#: operands; integer and boolean operands use `_INT_FORMS` where the forms differ.
_FLOAT_FORMS: dict[str, str] = {
    "add": "{0} + {1}", "sub": "{0} - {1}", "mul": "{0} * {1}", "div": "{0} / {1}",
    "neg": "-{0}", "rem": "fmod({0}, {1})", "pow": "pow({0}, {1})", "atan2": "atan2({0}, {1})",
    "nextafter": "nextafter({0}, {1})",
    "max": "mrjax__max({0}, {1})", "min": "mrjax__min({0}, {1})",
    "abs": "fabs({0})", "sign": "mrjax__sign({0})", "square": "{0} * {0}",
    "sqrt": "sqrt({0})", "rsqrt": "1.0 / sqrt({0})", "cbrt": "cbrt({0})",
    "exp": "exp({0})", "exp2": "exp2({0})", "expm1": "expm1({0})", "log": "log({0})",
    "log1p": "log1p({0})", "logistic": "1.0 / (1.0 + exp(-{0}))",
    "tanh": "tanh({0})", "sinh": "sinh({0})", "cosh": "cosh({0})", "asinh": "asinh({0})",
    "acosh": "acosh({0})", "atanh": "atanh({0})", "sin": "sin({0})", "cos": "cos({0})",
    "tan": "tan({0})", "asin": "asin({0})", "acos": "acos({0})", "atan": "atan({0})",
    "erf": "erf({0})", "erfc": "erfc({0})", "lgamma": "lgamma({0})",
    "floor": "floor({0})", "ceil": "ceil({0})", "is_finite": "isfinite({0})",
    "eq": "{0} == {1}", "ne": "{0} != {1}", "lt": "{0} < {1}", "le": "{0} <= {1}",
    "gt": "{0} > {1}", "ge": "{0} >= {1}",
}
_INT_FORMS: dict[str, str] = {
    "rem": "{0} % {1}", "max": "(({0}) > ({1}) ? ({0}) : ({1}))",
    "min": "(({0}) < ({1}) ? ({0}) : ({1}))", "abs": "(({0}) < 0 ? -({0}) : ({0}))",
    "sign": "((({0}) > 0) - (({0}) < 0))", "and": "{0} & {1}", "or": "{0} | {1}",
    "xor": "{0} ^ {1}", "not": "~{0}",
}
_BOOL_FORMS: dict[str, str] = {"and": "{0} && {1}", "or": "{0} || {1}", "xor": "{0} != {1}",
                               "not": "!{0}"}
#: Element-wise primitives whose `_FLOAT_FORMS` form holds for any dtype.
_ANY_KIND = ("add", "sub", "mul", "div", "neg", "eq", "ne", "lt", "le", "gt", "ge", "square")
#: Primitives with no run-time code: they move, copy or relabel elements.
_STRUCTURAL = ("broadcast_in_dim", "reshape", "squeeze", "slice", "concatenate", "stack",
               "split", "transpose", "rev", "iota", "copy", "stop_gradient",
               "optimization_barrier", "reduce_precision", "dynamic_slice")
#: Primitives that hold a jaxpr, inlined (some names are those of other JAX versions).
_CALLS = ("jit", "pjit", "closed_call", "core_call", "custom_jvp_call", "custom_vjp_call",
          "custom_vjp_call_jaxpr", "remat2", "checkpoint")
_OTHER = ("convert_element_type", "select_n", "clamp", "integer_pow", "round", "dot_general",
          "reduce_sum", "reduce_max", "reduce_min", "reduce_prod", "scan", "cond")
#: Every primitive the emitter translates into C99.
PRIMITIVES: tuple[str, ...] = tuple(sorted(
    set(_FLOAT_FORMS) | set(_INT_FORMS) | set(_BOOL_FORMS) | set(_STRUCTURAL) | set(_CALLS)
    | set(_OTHER)))

#: The helper functions a translation may call (emitted once, before the functions).
PRELUDE = """\
static double mrjax__max(double a, double b) { return (a != a || a > b) ? a : b; }
static double mrjax__min(double a, double b) { return (a != a || a < b) ? a : b; }
static double mrjax__sign(double a) { return a > 0.0 ? 1.0 : (a < 0.0 ? -1.0 : a); }
"""


class UnsupportedPrimitive(InputError):
    """A traced function uses a JAX primitive (or a dtype) that has no C99 translation."""


_CTYPES = {"float64": "double", "float32": "float", "int64": "long long", "int32": "int",
           "int16": "int", "int8": "int", "uint32": "unsigned int", "uint8": "unsigned int",
           "uint64": "unsigned long long", "bool": "int"}


def _ctype(dtype, where: str) -> str:
    name = np.dtype(dtype).name
    if name not in _CTYPES:
        raise UnsupportedPrimitive(f"{where}: dtype {name} has no C99 translation")
    return _CTYPES[name]


def c_literal(value, dtype) -> str:
    """A C99 literal of `value` in `dtype` (round-trip exact for floating point)."""
    kind = np.dtype(dtype).kind
    if kind == "b":
        return "1" if bool(value) else "0"
    if kind in "iu":
        v = int(value)
        suffix = ("U" if kind == "u" else "") + ("LL" if np.dtype(dtype).itemsize == 8 else "")
        return f"({v}{suffix})" if v < 0 else f"{v}{suffix}"
    v = float(value)
    if math.isnan(v):
        text = "NAN"
    elif math.isinf(v):
        text = "INFINITY" if v > 0 else "(-INFINITY)"
    else:
        text = repr(v)
        text = f"({text})" if text.startswith("-") else text
    return f"((float){text})" if np.dtype(dtype).name == "float32" else text


# ------------------------------------------------------------------------------ statements
@dataclasses.dataclass
class _Def:
    """`const ctype name = expr;` (or a mutable variable, `mutable`)."""

    name: str
    ctype: str
    expr: str
    deps: tuple[str, ...]
    mutable: bool = False


@dataclasses.dataclass
class _Assign:
    """`target = expr;` (`target` a mutable variable or an output element)."""

    target: str
    expr: str
    deps: tuple[str, ...]
    root: bool = False  # an output element: always kept


@dataclasses.dataclass
class _Loop:
    count: int
    index: str
    body: list


@dataclasses.dataclass
class _If:
    branches: list  # [(condition or None, deps, body)]


def _walk(stmts):
    for s in stmts:
        yield s
        if isinstance(s, _Loop):
            yield from _walk(s.body)
        elif isinstance(s, _If):
            for _, _, body in s.branches:
                yield from _walk(body)


def _live(stmts) -> set[str]:
    """Names whose values an output needs (a fixed point over the statement tree)."""
    live: set[str] = set()
    changed = True
    while changed:
        changed = False
        for s in _walk(stmts):
            if isinstance(s, _Def) and s.name in live or isinstance(s, _Assign) and (
                    s.root or s.target in live):
                new = set(s.deps) - live
                if new:
                    live |= new
                    changed = True
            elif isinstance(s, _If) and _any_live(s, live):
                new = {d for _, deps, _ in s.branches for d in deps} - live
                if new:
                    live |= new
                    changed = True
    return live


def _any_live(s, live) -> bool:
    return any(isinstance(t, _Def) and t.name in live or isinstance(t, _Assign) and (
        t.root or t.target in live) for _, _, body in s.branches for t in _walk(body))


def _render(stmts, live, indent: str) -> list[str]:
    out = []
    for s in stmts:
        if isinstance(s, _Def) and s.name in live:
            const = "" if s.mutable else "const "
            out.append(f"{indent}{const}{s.ctype} {s.name} = {s.expr};")
        elif isinstance(s, _Assign) and (s.root or s.target in live):
            out.append(f"{indent}{s.target} = {s.expr};")
        elif isinstance(s, _Loop):
            body = _render(s.body, live, indent + "    ")
            if body:
                out.append(f"{indent}for (int {s.index} = 0; {s.index} < {s.count}; "
                           f"++{s.index}) {{")
                out += body + [f"{indent}}}"]
        elif isinstance(s, _If) and _any_live(s, live):
            for k, (cond, _, body) in enumerate(s.branches):
                head = "if" if k == 0 else "} else if"
                out.append(f"{indent}{head} ({cond}) {{" if cond is not None else
                           f"{indent}}} else {{")
                out += _render(body, live, indent + "    ")
            out.append(f"{indent}}}")
    return out


# ------------------------------------------------------------------------------ values
@dataclasses.dataclass
class _Val:
    """A jaxpr value: C expressions per element (an object array of the value's shape), its
    dtype, and the Python value of each element known at translation time (or None)."""

    elems: np.ndarray
    dtype: np.dtype
    known: np.ndarray

    @property
    def shape(self):
        return self.elems.shape


def _const_val(value, dtype=None) -> _Val:
    a = np.asarray(value, dtype=dtype)
    elems = np.empty(a.shape, object)
    known = np.empty(a.shape, object)
    for idx in np.ndindex(a.shape):
        elems[idx] = c_literal(a[idx], a.dtype)
        known[idx] = a[idx].item()
    return _Val(elems, a.dtype, known)


def _map(v: _Val, fn) -> _Val:
    """A structural rearrangement of `v`'s elements (`fn` applied to the object arrays)."""
    return _Val(fn(v.elems), v.dtype, fn(v.known))


def _dtype_of(var) -> np.dtype:
    return np.dtype(var.aval.dtype)


class _Translator:
    """Translates jaxprs into statements (see the module docstring)."""

    def __init__(self, where: str):
        self.where = where
        self.count = itertools.count()
        self.names: set[str] = set()
        self.stmts: list = []

    # -- emission helpers
    def fresh(self, prefix: str = "t") -> str:
        name = f"{prefix}{next(self.count)}"
        self.names.add(name)
        return name

    def deps(self, *exprs: str) -> tuple[str, ...]:
        return tuple(e for e in exprs if e in self.names)

    def define(self, expr: str, dtype, operands: Sequence[str], known=None) -> tuple[str, object]:
        if known is not None:
            return c_literal(known, dtype), known
        name = self.fresh()
        self.stmts.append(_Def(name, _ctype(dtype, self.where), expr, self.deps(*operands)))
        return name, None

    def unsupported(self, what: str):
        raise UnsupportedPrimitive(f"{self.where}: the JAX primitive {what!r} has no C99 "
                                   f"translation in mrjax's emitter (see "
                                   f"mrjax.export.PRIMITIVES)")

    # -- jaxprs
    def jaxpr(self, jaxpr, consts: Sequence, args: Sequence[_Val]) -> list[_Val]:
        env: dict = {}
        for var, c in zip(jaxpr.constvars, consts):
            env[var] = c if isinstance(c, _Val) else _const_val(c, _dtype_of(var))
        for var, a in zip(jaxpr.invars, args):
            env[var] = a

        def read(v):
            if isinstance(v, core.Literal):
                return _const_val(v.val, np.dtype(v.aval.dtype))
            return env[v]

        for eqn in jaxpr.eqns:
            outs = self.eqn(eqn, [read(v) for v in eqn.invars])
            for var, val in zip(eqn.outvars, outs):
                if not isinstance(var, core.DropVar):
                    env[var] = val
        return [read(v) for v in jaxpr.outvars]

    def closed(self, closed, args: Sequence[_Val]) -> list[_Val]:
        if isinstance(closed, core.ClosedJaxpr):
            return self.jaxpr(closed.jaxpr, closed.consts, args)
        return self.jaxpr(closed, [], args)

    # -- one equation
    def eqn(self, eqn, ins: list[_Val]) -> list[_Val]:
        name = eqn.primitive.name
        p = eqn.params
        outs = [(tuple(v.aval.shape), _dtype_of(v)) for v in eqn.outvars]
        if name in _CALLS:
            return self.call(name, p, ins)
        if name in _STRUCTURAL:
            return self.structural(name, p, ins, outs)
        if name == "scan":
            return self.scan(p, ins)
        if name == "cond":
            return self.cond(p, ins, outs)
        if name == "dot_general":
            return [self.dot_general(p, ins, outs[0])]
        if name in ("reduce_sum", "reduce_max", "reduce_min", "reduce_prod"):
            return [self.reduce(name, p["axes"], ins[0], outs[0])]
        return [self.elementwise(name, p, ins, outs[0])]

    def call(self, name, p, ins):
        inner = p.get("jaxpr") or p.get("call_jaxpr") or p.get("fun_jaxpr")
        if inner is None:
            self.unsupported(name)
        return self.closed(inner, ins)

    def structural(self, name, p, ins, outs):
        shape = outs[0][0]
        if name == "iota":
            dt = np.dtype(p["dtype"])
            idx = np.indices(shape)[p["dimension"]] if shape else np.zeros((), int)
            return [_const_val(idx.astype(dt), dt)]
        v = ins[0]
        if name in ("copy", "stop_gradient"):
            return [v]
        if name == "optimization_barrier":
            return list(ins)
        if name == "reduce_precision":
            if (p["exponent_bits"], p["mantissa_bits"]) != (11, 52) or v.dtype != np.float64:
                self.unsupported("reduce_precision")
            return [v]
        if name in ("reshape", "squeeze"):
            if p.get("dimensions") not in (None, ()) and name == "reshape":
                self.unsupported("reshape with a dimension order")
            return [_map(v, lambda a: a.reshape(shape))]
        if name == "broadcast_in_dim":
            dims = p["broadcast_dimensions"]
            mid = [1] * len(shape)
            for i, d in enumerate(dims):
                mid[d] = v.shape[i]
            return [_map(v, lambda a: np.broadcast_to(a.reshape(mid), shape).copy())]
        if name == "slice":
            strides = p["strides"] or (1,) * len(v.shape)
            sl = tuple(slice(a, b, s) for a, b, s in zip(p["start_indices"], p["limit_indices"],
                                                          strides))
            return [_map(v, lambda a: a[sl])]
        if name == "dynamic_slice":
            return [self.dynamic_slice(v, ins[1:], p["slice_sizes"])]
        if name == "concatenate":
            d = p["dimension"]
            return [_Val(np.concatenate([a.elems for a in ins], d), v.dtype,
                         np.concatenate([a.known for a in ins], d))]
        if name == "stack":
            ax = p["axis"]
            return [_Val(np.stack([a.elems for a in ins], ax), v.dtype,
                         np.stack([a.known for a in ins], ax))]
        if name == "split":
            cuts = np.cumsum(p["sizes"])[:-1]
            ax = p["axis"]
            return [_Val(e, v.dtype, k) for e, k in zip(np.split(v.elems, cuts, ax),
                                                       np.split(v.known, cuts, ax))]
        if name == "transpose":
            return [_map(v, lambda a: a.transpose(p["permutation"]))]
        return [_map(v, lambda a: np.flip(a, p["dimensions"]))]  # rev

    def dynamic_slice(self, v: _Val, starts: Sequence[_Val], sizes) -> _Val:
        begin = []
        for d, s in enumerate(starts):
            k = s.known.reshape(-1)[0]
            if k is None:
                self.unsupported("dynamic_slice with an index computed at run time")
            begin.append(min(max(int(k), 0), v.shape[d] - sizes[d]))  # XLA clamps the start
        sl = tuple(slice(b, b + n) for b, n in zip(begin, sizes))
        return _map(v, lambda a: a[sl])

    # -- element-wise
    def form(self, name: str, dtype: np.dtype) -> str:
        """The C form of an element-wise primitive on operands of `dtype`."""
        kind = dtype.kind
        if kind == "b" and name in _BOOL_FORMS:
            return _BOOL_FORMS[name]
        if kind in "iub" and name in _INT_FORMS:
            return _INT_FORMS[name]
        if name in _FLOAT_FORMS and (kind == "f" or name in _ANY_KIND):
            return _FLOAT_FORMS[name]
        self.unsupported(name if kind == "f" else f"{name} on {dtype.name}")

    def elementwise(self, name, p, ins, out) -> _Val:
        shape, dtype = out
        if name not in PRIMITIVES:
            self.unsupported(name)
        ins = [_map(a, lambda e: np.broadcast_to(e, shape)) for a in ins]
        elems = np.empty(shape, object)
        known = np.empty(shape, object)
        for idx in np.ndindex(shape):
            ops = [a.elems[idx] for a in ins]
            kn = [a.known[idx] for a in ins]
            elems[idx], known[idx] = self.scalar(name, p, ops, kn, [a.dtype for a in ins], dtype)
        return _Val(elems, dtype, known)

    def scalar(self, name, p, ops, kn, dtypes, dtype):
        """One element of an element-wise primitive: `(C expression, known value)`."""
        fold = _fold(name, kn, dtype) if all(k is not None for k in kn) else None
        if name == "select_n":
            return self.select(ops, kn, dtypes[0], dtype)
        if name == "convert_element_type":
            expr = f"{ops[0]} != 0" if dtype.kind == "b" else f"({_ctype(dtype, self.where)})" \
                f"{ops[0]}"
            return self.define(expr, dtype, ops, fold)
        if name == "clamp":
            lo, x, hi = ops
            f = ("mrjax__min(mrjax__max({1}, {0}), {2})" if dtype.kind == "f"
                 else "({1} < {0}) ? {0} : (({1} > {2}) ? {2} : {1})")
            return self.define(f.format(lo, x, hi), dtype, ops, fold)
        if name == "integer_pow":
            return self.integer_pow(ops[0], int(p["y"]), dtype, fold)
        if name == "round":
            method = int(getattr(p["rounding_method"], "value", p["rounding_method"]))
            if dtype.kind != "f":
                self.unsupported("round on integers")
            return self.define(f"{'round' if method == 0 else 'nearbyint'}({ops[0]})", dtype,
                               ops, fold)
        form = self.form(name, dtypes[0])
        expr = form.format(*ops)
        if dtype.name == "float32" and "(" in form:
            expr = f"(float)({expr})"
        return self.define(expr, dtype, ops, fold)

    def select(self, ops, kn, which_dtype, dtype):
        """`select_n(which, *cases)`: the case `which` picks (a known `which` picks at
        translation time)."""
        which, cases = ops[0], ops[1:]
        if kn[0] is not None:
            k = min(max(int(kn[0]), 0), len(cases) - 1)
            return cases[k], kn[1 + k]
        if which_dtype.kind == "b":
            return self.define(f"{which} ? {cases[1]} : {cases[0]}", dtype, ops)
        expr = cases[-1]
        for k in range(len(cases) - 2, -1, -1):
            expr = f"({which} == {k}) ? {cases[k]} : ({expr})"
        return self.define(expr, dtype, ops)

    def integer_pow(self, x: str, y: int, dtype, fold):
        """x**y by binary powering, as JAX lowers `integer_pow`."""
        if fold is not None:
            return c_literal(fold, dtype), fold
        if y == 0:
            return c_literal(1, dtype), 1
        acc, base, n = None, x, abs(y)
        while n > 0:
            if n & 1:
                acc = base if acc is None else self.define(f"{acc} * {base}", dtype,
                                                           (acc, base))[0]
            n >>= 1
            if n > 0:
                base = self.define(f"{base} * {base}", dtype, (base,))[0]
        if y < 0:
            acc = self.define(f"{c_literal(1, dtype)} / {acc}", dtype, (acc,))[0]
        return acc, None

    def dot_general(self, p, ins, out) -> _Val:
        (lc, rc), (lb, rb) = p["dimension_numbers"]
        a, b = ins
        shape, dtype = out
        lfree = [d for d in range(a.elems.ndim) if d not in lc and d not in lb]
        rfree = [d for d in range(b.elems.ndim) if d not in rc and d not in rb]
        A = a.elems.transpose(list(lb) + lfree + list(lc))
        B = b.elems.transpose(list(rb) + rfree + list(rc))
        nb, nl, nr = len(lb), len(lfree), len(rfree)
        A = A.reshape(A.shape[:nb + nl] + (-1,))
        B = B.reshape(B.shape[:nb + nr] + (-1,))
        elems = np.empty(shape, object)
        for idx in np.ndindex(shape):
            bi, li, ri = idx[:nb], idx[nb:nb + nl], idx[nb + nl:]
            terms = [f"{x} * {y}" for x, y in zip(A[bi + li], B[bi + ri])]
            ops = list(A[bi + li]) + list(B[bi + ri])
            expr = " + ".join(terms) if terms else c_literal(0, dtype)
            elems[idx] = self.define(expr, dtype, ops)[0]
        return _Val(elems, dtype, np.full(shape, None, object))

    def reduce(self, name, axes, v: _Val, out) -> _Val:
        shape, dtype = out
        keep = [d for d in range(v.elems.ndim) if d not in axes]
        E = v.elems.transpose(keep + list(axes)).reshape(shape + (-1,))
        op = {"reduce_sum": "add", "reduce_max": "max", "reduce_min": "min",
              "reduce_prod": "mul"}[name]
        elems = np.empty(shape, object)
        for idx in np.ndindex(shape):
            row = list(E[idx])
            acc = row[0] if row else c_literal({"add": 0, "mul": 1}.get(op, 0), dtype)
            for e in row[1:]:
                acc = self.scalar(op, {}, [acc, e], [None, None], [dtype, dtype], dtype)[0]
            elems[idx] = acc
        return _Val(elems, dtype, np.full(shape, None, object))

    # -- control flow
    def mutable(self, v: _Val) -> _Val:
        """Fresh mutable variables initialised to `v`."""
        elems = np.empty(v.shape, object)
        for idx in np.ndindex(v.shape):
            name = self.fresh("c")
            self.stmts.append(_Def(name, _ctype(v.dtype, self.where), v.elems[idx],
                                   self.deps(v.elems[idx]), mutable=True))
            elems[idx] = name
        return _Val(elems, v.dtype, np.full(v.shape, None, object))

    def block(self, fn) -> list:
        outer, self.stmts = self.stmts, []
        try:
            fn()
            return self.stmts
        finally:
            self.stmts = outer

    def assign(self, targets: Sequence[_Val], values: Sequence[_Val]) -> None:
        """Copy `values` to fresh temporaries, then into `targets` (a swap stays correct)."""
        temps = []
        for v in values:
            t = np.empty(v.shape, object)
            for idx in np.ndindex(v.shape):
                t[idx] = self.define(v.elems[idx], v.dtype, (v.elems[idx],))[0]
            temps.append(t)
        for tgt, t in zip(targets, temps):
            for idx in np.ndindex(tgt.shape):
                self.stmts.append(_Assign(tgt.elems[idx], t[idx], self.deps(t[idx])))

    def scan(self, p, ins) -> list[_Val]:
        nc, nk = p["num_consts"], p["num_carry"]
        body = p["jaxpr"]
        if len(ins) > nc + nk or len(body.jaxpr.outvars) > nk:
            self.unsupported("scan over arrays")
        if p.get("unroll", 1) not in (1, True, False) and not isinstance(p.get("unroll"), int):
            self.unsupported("scan")
        consts, carry = ins[:nc], [self.mutable(v) for v in ins[nc:]]

        def run():
            outs = self.closed(body, consts + carry)
            self.assign(carry, outs)

        self.stmts.append(_Loop(int(p["length"]), self.fresh("k"), self.block(run)))
        return carry

    def cond(self, p, ins, outs) -> list[_Val]:
        index, ops = ins[0], ins[1:]
        n = len(p["branches"])
        k = index.known.reshape(-1)[0]
        if k is not None:  # the branch is known at translation time
            return self.closed(p["branches"][min(max(int(k), 0), n - 1)], ops)
        results = [self.mutable(_const_val(np.zeros(shape, dt), dt)) for shape, dt in outs]
        i = index.elems.reshape(-1)[0]
        branches = []
        for k, br in enumerate(p["branches"]):
            def run(br=br):
                self.assign(results, self.closed(br, ops))

            cond = (None if k == n - 1 and k > 0 else
                    f"{i} <= 0" if k == 0 and n > 1 else "1" if n == 1 else f"{i} == {k}")
            branches.append((cond, self.deps(i), self.block(run)))
        self.stmts.append(_If(branches))
        return results


def _fold(name, kn, dtype):
    """The value of an element-wise primitive on known operands (None where not folded:
    only exact IEEE operations are folded, so a folded value is what the C would compute)."""
    cast = np.dtype(dtype).type
    try:
        if name == "convert_element_type":
            return cast(kn[0]).item()
        exact = {"add": lambda a, b: a + b, "sub": lambda a, b: a - b,
                 "mul": lambda a, b: a * b, "neg": lambda a: -a}
        if name in exact and np.dtype(dtype).kind in "fiu":
            with np.errstate(all="ignore"):
                return cast(exact[name](*(cast(k) for k in kn))).item()
    except (TypeError, ValueError, OverflowError):
        return None
    return None


def translate(fn_name: str, closed, inputs: Sequence[tuple[str, tuple[int, ...]]],
              outputs: Sequence[str], *, where: str) -> str:
    """One C99 function from a closed jaxpr.

    **Arguments:**

    - `fn_name`: the C function's name (it is `static`).
    - `closed`: the `jax.extend.core.ClosedJaxpr` of the function (float64 inputs).
    - `inputs`: `(name, shape)` per jaxpr input; a scalar becomes a `double` parameter, an
        array a `const double *` read element by element in row-major order.
    - `outputs`: one name per jaxpr output, each a `double *` parameter written element by
        element.
    - `where`: what is translated, for the error message.

    **Returns:** the C text (it may call the helpers of :data:`PRELUDE`, emitted before it).

    Raises :class:`UnsupportedPrimitive` (one line) for a primitive outside
    :data:`PRIMITIVES`.
    """
    tr = _Translator(where)
    args, params = [], []
    for (name, shape), var in zip(inputs, closed.jaxpr.invars):
        dt = _dtype_of(var)
        if dt != np.float64:
            raise UnsupportedPrimitive(f"{where}: input {name} must be float64, not {dt.name}")
        if shape == ():
            params.append(f"double {name}")
            args.append(_Val(np.array(name, object).reshape(()), dt, np.full((), None, object)))
        else:
            params.append(f"const double *{name}")
            e = np.array([f"{name}[{i}]" for i in range(int(np.prod(shape)))], object)
            args.append(_Val(e.reshape(shape), dt, np.full(shape, None, object)))
    tr.names.update(n for n, _ in inputs)
    results = tr.closed(closed, args)
    for name, val in zip(outputs, results):
        params.append(f"double *{name}")
        for k, e in enumerate(val.elems.reshape(-1)):
            tr.stmts.append(_Assign(f"{name}[{k}]", e, tr.deps(e), root=True))
    live = _live(tr.stmts)
    body = [f"    (void){n};" for n, _ in inputs] + _render(tr.stmts, live, "    ")
    head = f"static void {fn_name}({', '.join(params)})"
    return head + "\n{\n" + "\n".join(body) + "\n}\n"


def trace(fn: Callable, *shapes: tuple[int, ...]):
    """`jax.make_jaxpr(fn)` on float64 zeros of `shapes` (the closed jaxpr to translate)."""
    return jax.make_jaxpr(fn)(*(np.zeros(s, np.float64) for s in shapes))
