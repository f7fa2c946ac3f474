"""The C99 target: a header and a source file with the model, its state and its inverse."""

from __future__ import annotations

import dataclasses
import math
import textwrap

from .. import __version__
from ._emit import PRELUDE, c_literal, trace, translate
from ._model import ControllerModel, check_names

_HEADER = """\
#ifndef {guard}
#define {guard}

/* Number of doubles of one damper's state. */
#define {P}_STATE_SIZE {N}
/* The admissible command [{unit}]. */
#define {P}_COMMAND_MIN {lo}
#define {P}_COMMAND_MAX {hi}

/* {N}: the size of the state array each damper needs. */
int {p}_state_size(void);

/* Set the state at the first sample: displacement x [m], velocity xdot [m/s], command [{unit}]. */
void {p}_init(double *state, double x, double xdot, double command);

/* The force [N] at (x [m], xdot [m/s]) with `command` [{unit}] at this sample, after
   advancing the state from the previous sample over dt [s] (the excitation taken linear in
   between). dt = 0: no time passes (the force at the same sample; the command is recorded). */
double {p}_step(double *state, double x, double xdot, double command, double dt);

/* The command [{unit}] in the admissible range whose force at this sample is closest to
   desired_force [N]; `state` (unchanged) is the one {p}_step returned at this sample
   (x [m], xdot [m/s]). {inverse_doc}
   Out of reach, it saturates at the range's end whose force is closest. */
double {p}_inverse(const double *state, double x, double xdot, double desired_force, double dt);

#endif
"""

_NO_LAG = ("Without a command lag, the command acts at once: passing it to {p}_step at\n"
           "   this sample (dt = 0) gives that force; dt [s] is unused.")
_LAG = ("With the command lag, a command acts through the lag's output u: this returns\n"
        "   the command that, held over the next interval dt [s], brings u to the u whose force\n"
        "   here is closest (dt = 0: that u); record it with {p}_step(state, x, xdot, command,\n"
        "   0) so that the next step holds it.")

_API = """\
int {p}_state_size(void)
{{
    return {P}_STATE_SIZE;
}}

void {p}_init(double *state, double x, double xdot, double command)
{{
    {p}__initial(x, xdot, command, state);
}}

double {p}_step(double *state, double x, double xdot, double command, double dt)
{{
    double next[{P}_STATE_SIZE];
    double force;
    int k;
    {p}__step(state, x, xdot, command, dt, next, &force);
    for (k = 0; k < {P}_STATE_SIZE; ++k)
        state[k] = next[k];
    return force;
}}

static double {p}__force(const double *state, double x, double xdot, double u, double desired)
{{
    double force;
    {p}__output(state, x, xdot, u, &force);
    return force - desired;
}}

/* A grid of N_GRID commands over the range; bisection in the first bracket of a sign change
   (the smallest command giving the force), else golden-section search of |force - desired|
   beside the best node: at most N_GRID + 2 ITERS + 2 force evaluations, a fixed count. */
double {p}_inverse(const double *state, double x, double xdot, double desired_force, double dt)
{{
    enum {{ N_GRID = {n_grid}, ITERS = {iters} }};
    const double lo = {P}_COMMAND_MIN, hi = {P}_COMMAND_MAX;
    double grid[N_GRID], g[N_GRID];
    double a, b, u;
    int k, j = 0, first = -1;
    for (k = 0; k < N_GRID; ++k) {{
        grid[k] = k == 0 ? lo : (k == N_GRID - 1 ? hi : lo + (hi - lo) * ((double)k / (N_GRID - 1)));
        g[k] = {p}__force(state, x, xdot, grid[k], desired_force);
        if (fabs(g[k]) < fabs(g[j]))
            j = k;
        if (k > 0 && first < 0 && (g[k - 1] <= 0.0) != (g[k] <= 0.0))
            first = k - 1;
    }}
    if (first >= 0) {{
        double ga = g[first];
        a = grid[first];
        b = grid[first + 1];
        for (k = 0; k < ITERS; ++k) {{
            const double mid = 0.5 * (a + b);
            const double gm = {p}__force(state, x, xdot, mid, desired_force);
            if ((gm <= 0.0) == (ga <= 0.0)) {{
                a = mid;
                ga = gm;
            }} else {{
                b = mid;
            }}
        }}
        u = fabs({p}__force(state, x, xdot, a, desired_force))
            <= fabs({p}__force(state, x, xdot, b, desired_force)) ? a : b;
    }} else {{
        const double r = {golden};
        a = grid[j > 0 ? j - 1 : 0];
        b = grid[j < N_GRID - 1 ? j + 1 : N_GRID - 1];
        for (k = 0; k < ITERS; ++k) {{
            const double c = b - r * (b - a), d = a + r * (b - a);
            if (fabs({p}__force(state, x, xdot, c, desired_force))
                <= fabs({p}__force(state, x, xdot, d, desired_force)))
                b = d;
            else
                a = c;
        }}
        u = 0.5 * (a + b);
        u = fabs({p}__force(state, x, xdot, grid[j], desired_force))
            <= fabs({p}__force(state, x, xdot, u, desired_force)) ? grid[j] : u;
    }}
    u = u < lo ? lo : (u > hi ? hi : u);
{lag}    (void)dt;
    return u;
}}
"""

_LAG_CODE = """\
    if (dt > 0.0) {{ /* the command that brings the lag's output to u over dt */
        const double a_lag = exp(-{eta} * dt);
        u = (u - a_lag * state[{iu}]) / (1.0 - a_lag);
        u = u < lo ? lo : (u > hi ? hi : u);
    }}
"""


@dataclasses.dataclass(frozen=True)
class C99:
    """The C99 target: `PREFIX_model.h` and `PREFIX_model.c` (double precision, no allocation,
    only `<math.h>`; link with `-lm`) with the API `PREFIX_state_size`, `PREFIX_init`,
    `PREFIX_step` and `PREFIX_inverse` (see the header each export writes).

    **Fields:** `prefix` of every public name (a C identifier, default `"mrjax"`).
    """

    prefix: str = "mrjax"

    def __post_init__(self):
        check_names([self.prefix])

    def files(self, cm: ControllerModel) -> dict[str, bytes]:
        """`{"PREFIX_model.h": ..., "PREFIX_model.c": ...}` of `cm`. Raises
        :class:`mrjax.export.UnsupportedPrimitive` (one line) where the model's JAX functions
        use a primitive without a C translation."""
        header, source = c_sources(cm, self.prefix)
        return {f"{self.prefix}_model.h": header.encode(), f"{self.prefix}_model.c":
                source.encode()}


def c_sources(cm: ControllerModel, prefix: str) -> tuple[str, str]:
    """`(header, source)` text of `cm` with public names starting `prefix`."""
    p, P = prefix, prefix.upper()
    N = cm.state_size
    where = f"model {cm.model.name!r}"
    parts = [
        translate(f"{p}__initial", trace(cm.initial, (), (), ()), [("x", ()), ("xdot", ()),
                  ("command", ())], ["state"], where=where),
        translate(f"{p}__step", trace(cm.step, (N,), (), (), (), ()),
                  [("state", (N,)), ("x", ()), ("xdot", ()), ("command", ()), ("dt", ())],
                  ["next", "force"], where=where),
        translate(f"{p}__output", trace(cm.output, (N,), (), (), ()),
                  [("state", (N,)), ("x", ()), ("xdot", ()), ("u", ())], ["force"], where=where),
    ]
    lo, hi = cm.command_range
    unit = cm.laws.command_unit
    doc = (_LAG if cm.laws.lag is not None else _NO_LAG).format(p=p)
    fields = dict(p=p, P=P, N=N, lo=c_literal(lo, "float64"), hi=c_literal(hi, "float64"),
                  unit=unit, guard=f"{P}_MODEL_H", inverse_doc=doc)
    header = _banner(cm, f"{p}_model.h") + "\n" + _HEADER.format(**fields)
    used = "".join(parts)
    helpers = [line for line in PRELUDE.splitlines() if line.split("(")[0].split()[-1] in used]
    lag = "" if cm.laws.lag is None else _LAG_CODE.format(
        eta=c_literal(cm.laws.lag, "float64"), iu=cm.model_state_size + 2)
    api = _API.format(p=p, P=P, n_grid=cm.n_grid, iters=cm.iters, lag=lag,
                      golden=c_literal(0.5 * (math.sqrt(5.0) - 1.0), "float64"))
    source = "\n".join([_banner(cm, f"{p}_model.c"), "#include <math.h>", "",
                        f'#include "{p}_model.h"', "", *helpers, "",
                        *parts, api])
    return header, source


def _banner(cm: ControllerModel, name: str) -> str:
    """The comment at the top of each file: what it is, from what, in which units."""
    lines = [f"{name}: an identified MR damper model and its inverse, generated by mrjax "
             f"{__version__} from its JAX functions.", ""]
    lines += cm.summary()
    if cm.source:
        lines.append(f"from: {cm.source}")
    if cm.sha256:
        lines.append(f"fit.json SHA-256: {cm.sha256}")
    unit = cm.laws.command_unit
    lines += ["", f"Units: x [m], xdot [m/s], dt [s], force [N], command [{unit}]. The state is "
              f"{cm.state_size} doubles: the model's {cm.model_state_size} state values, then x, "
              "xdot, the effective command (after the lag) and the command at the last sample.",
              "C99, double precision, no allocation, no global state (one state array per "
              "damper), only <math.h>."]
    body = []
    for line in lines:
        body += textwrap.wrap(line, 92, subsequent_indent="    ") if line else [""]
    body = [b.replace("*/", "* /") for b in body]  # nothing may close the comment early
    return "/*\n" + "\n".join(f" * {b}".rstrip() for b in body) + "\n */\n"
