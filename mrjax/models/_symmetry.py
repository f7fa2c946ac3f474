r"""The scale symmetry of a hysteretic state: a family of parameter sets with the same force.

In Bouc-Wen-type models the hysteretic variable z has no unit of its own: the equations are
unchanged under $z \to s z$ with $\alpha \to \alpha/s$, $\delta \to s\delta$ and
$\beta, \gamma \to s^{1-n}\beta, s^{1-n}\gamma$. A fitted parameter vector is one point of that
one-parameter family; a joint fit, a posterior and a parameter count must fix the scale.
:class:`ScaleSymmetry` describes such a family for any model (`AbstractModel.scale_symmetry`),
so that no caller needs to know a model by its name.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping

import numpy as np
from jaxtyping import ArrayLike


@dataclasses.dataclass(frozen=True)
class ScaleSymmetry:
    r"""The force is unchanged when the state is scaled, $y_i \to s^{e_i} y_i$, and each
    parameter `p` named in `exponents` is multiplied by $s^{a_p + b_p \nu}$, $\nu$ the value of
    the parameter `power` (any $s > 0$).

    **Fields:**

    - `exponents`: `((name, a, b), ...)`, the parameters that move and their exponents
        $a + b\nu$ (Bouc-Wen: `alpha` (-1, 0), `delta` (1, 0), `beta` and `gamma` (1, -1)).
    - `power`: the parameter $\nu$ of the exponents (`"n"`), or None where they are constants.
    - `state`: the exponent $e_i$ of each state component (Bouc-Wen `(1,)`: z; modified
        Bouc-Wen `(0, 1)`: y stays, z scales).
    - `gauge`, `balance`: the canonical member of the family is the one with
        `gauge = sum(balance)` (Bouc-Wen: delta = beta + gamma, i.e.
        $|z|_{max} = (\delta/(\beta+\gamma))^{1/n} = 1$). `gauge` is also the parameter to hold
        to fix the scale (a posterior's gauge).
    - `held`: `((name, value), ...)` values of parameters the formulas read that the model
        holds fixed (`mrjax.models.fix`), e.g. a fixed `n`.

    All parameters named must be among the model's parameters or in `held`.
    """

    exponents: tuple[tuple[str, float, float], ...]
    gauge: str
    balance: tuple[str, ...]
    power: str | None = None
    state: tuple[float, ...] = (1.0,)
    held: tuple[tuple[str, float], ...] = ()

    def __post_init__(self):
        # tuples throughout (lists given are converted): the symmetry is hashable
        object.__setattr__(self, "exponents", tuple(
            (str(n), float(a), float(b)) for n, a, b in self.exponents))
        object.__setattr__(self, "balance", tuple(self.balance))
        object.__setattr__(self, "state", tuple(float(e) for e in self.state))
        object.__setattr__(self, "held", tuple((str(n), float(v)) for n, v in self.held))
        named = {e[0] for e in self.exponents}
        if self.gauge not in named or not set(self.balance) <= named:
            raise ValueError("ScaleSymmetry: gauge and balance must be among the exponents")
        if len({(a, b) for n, a, b in self.exponents if n in self.balance}) > 1:
            raise ValueError("ScaleSymmetry: the balance parameters need one common exponent")

    # ---------------------------------------------------------------------- reading
    @property
    def scaled(self) -> tuple[str, ...]:
        """The parameters that move with the scale."""
        return tuple(n for n, a, b in self.exponents if (a, b) != (0.0, 0.0))

    def _exponent(self, name: str) -> tuple[float, float]:
        for n, a, b in self.exponents:
            if n == name:
                return a, b
        return 0.0, 0.0

    def _column(self, theta: np.ndarray, names: tuple[str, ...], name: str) -> np.ndarray:
        held = dict(self.held)
        if name in held:
            return np.full(theta.shape[:-1], held[name])
        return theta[..., names.index(name)]

    def _power(self, theta, names) -> np.ndarray | float:
        return 0.0 if self.power is None else self._column(theta, names, self.power)

    def factors(self, theta: ArrayLike, names: tuple[str, ...], s: ArrayLike
                ) -> dict[str, np.ndarray]:
        """The factor (...) each moving parameter is multiplied by at scale `s` (...), for the
        parameters `theta` (..., P) named `names` (the model's `param_names`)."""
        theta = np.asarray(theta, float)
        nu = self._power(theta, names)
        return {n: _times(1.0, s, a, b, nu) for n, a, b in self.exponents}

    def canonical_scale(self, theta: ArrayLike, names: tuple[str, ...]) -> np.ndarray:
        """The scale `s` (...) that takes `theta` (..., P) to the canonical member of its family
        (`gauge = sum(balance)`); 1 where that member does not exist (a non-positive gauge or
        balance sum, or a non-positive exponent difference)."""
        return self._scale(np.asarray(theta, float), names, scalar=np.ndim(theta) == 1)

    def has_canonical(self, theta: ArrayLike, names: tuple[str, ...]) -> np.ndarray:
        """Whether the family of `theta` (..., P) has a canonical member (a positive gauge and
        balance sum, a positive exponent difference): where not, :meth:`canonical_scale` is 1."""
        theta = np.asarray(theta, float)
        return self._scale(theta, names, scalar=False, valid=True)

    def _scale(self, theta: np.ndarray, names: tuple[str, ...], scalar: bool,
               valid: bool = False):
        """:meth:`canonical_scale`, in scalar arithmetic (one row) or elementwise."""
        g = self._column(theta, names, self.gauge)
        bal = sum(self._column(theta, names, n) for n in self.balance)
        (ag, bg), (ab, bb) = self._exponent(self.gauge), self._exponent(self.balance[0])
        nu = self._power(theta, names)
        with np.errstate(all="ignore"):
            e = (ag - ab) + (bg - bb) * nu  # s**e = bal / g at the canonical member
            ratio = g / bal
            ok = np.isfinite(ratio) & (ratio > 0) & (bal > 0) & (e > 0)
            if valid:
                return ok
            if scalar:
                return ratio ** (-1.0 / e) if ok else np.float64(1.0)
            return np.where(ok, np.where(ok, ratio, 1.0) ** (-1.0 / np.where(ok, e, 1.0)), 1.0)

    def rescale(self, theta: ArrayLike, names: tuple[str, ...], s: ArrayLike) -> np.ndarray:
        """`theta` (..., P) moved along its family to scale `s` (...): the same force."""
        th = np.array(theta, dtype=float, copy=True)
        s = np.asarray(s, float)
        nu = self._power(th, names)
        with np.errstate(all="ignore"):
            for n, a, b in self.exponents:
                if n in names:
                    i = names.index(n)
                    th[..., i] = _times(th[..., i], s, a, b, nu)
        return th

    def canonical(self, theta: ArrayLike, names: tuple[str, ...]) -> np.ndarray:
        """`theta` (..., P) mapped to the canonical member of its family (same force); rows
        without one are returned as they are."""
        theta = np.asarray(theta, float)
        return self.rescale(theta, names, self._scale(theta, names, scalar=False))

    # ---------------------------------------------------------------------- holding
    def restrict(self, held: Mapping[str, float]) -> ScaleSymmetry | None:
        """The symmetry left when the parameters `held` are fixed at their values: None where
        a held parameter moves with the scale (it pins the scale: a fixed non-zero `delta`,
        or `beta` with `n` free or fixed at a value other than 1), else this symmetry with the
        held values it reads. A parameter held at 0 moves nowhere and pins nothing."""
        held = {**dict(self.held), **{k: float(v) for k, v in held.items()}}
        nu = held.get(self.power) if self.power is not None else 0.0
        for n, a, b in self.exponents:
            if n not in held or held[n] == 0.0:
                continue
            if nu is None:  # the exponent varies with the free power
                if (a, b) != (0.0, 0.0):
                    return None
            elif not math.isclose(a + b * nu, 0.0, abs_tol=1e-12):
                return None
        need = {n for n, _, _ in self.exponents} | ({self.power} if self.power else set())
        kept = tuple((n, v) for n, v in held.items() if n in need)
        return dataclasses.replace(self, held=kept)

    def pinned_by(self, held: Mapping[str, float]) -> bool:
        """Whether holding the parameters `held` at their values fixes the scale."""
        return self.restrict(held) is None


def _times(value, s, a: float, b: float, nu):
    """`value` times $s^{a + b\\nu}$ (a division for a negative exponent; exact products for
    the exponents +-1)."""
    if b == 0.0 and a == 1.0:
        return value * s
    if b == 0.0 and a == -1.0:
        return value / s
    return value / s ** (-a - b * nu) if a < 0 else s ** (a + b * nu) * value
