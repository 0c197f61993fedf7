"""C of an SX Function evaluated for several independent cases at once ("lanes").

CasADi's generated code evaluates one case: every operation of the SX algorithm on scalars. Here
every operation runs over ``lanes`` cases side by side (element ``j`` of an input or output for
lane ``b`` at ``[j * lanes + b]``, structure of arrays), so the C compiler turns the arithmetic
into vector instructions. The operations, their order and operands are the algorithm's own, in
the same C functions CasADi's generated code calls: each lane gives bit for bit what the scalar
code gives for that case (compiled without floating-point contraction, ``-ffp-contract=off``).

A sine and a cosine of the same operand become one ``sincos`` call where the C library is
glibc, whose ``sincos`` returns bit for bit its ``sin`` and ``cos`` (checked on 2e7 arguments,
glibc 2.36): a fifth of a fixed wing step's calls into the maths library, which the lanes
cannot vectorise bit for bit.

``vector_math=True`` (four lanes only) evaluates the maths library's functions four lanes in
one call of glibc's vector library ``libmvec`` (AVX2; :func:`vector_math_unavailable` says
whether this machine has it): much of a Monte-Carlo step's time is those scalar calls.
``libmvec`` is accurate to a few units in the last place, not bit for bit the scalar functions:
results then agree with the scalar code to round-off, not to the last bit.
"""

from __future__ import annotations

import math
import platform
from functools import cache

import casadi as ca

from uavdyn.integrate.compiler import find_compiler

_NAMES = {getattr(ca, n): n[3:] for n in dir(ca) if n.startswith("OP_")}
_UNARY = {"NEG": "-{0}", "SQ": "{0}*{0}", "TWICE": "2.*{0}", "INV": "1./{0}", "NOT": "!{0}",
          "ASSIGN": "{0}", "SIGN": "{0}<0 ? -1 : {0}>0 ? 1 : {0}"}
_UNARY.update({op.upper(): op + "({0})" for op in (
    "exp", "log", "sqrt", "sin", "cos", "tan", "asin", "acos", "atan", "sinh", "cosh", "tanh",
    "asinh", "acosh", "atanh", "floor", "ceil", "fabs", "erf", "expm1", "log1p")})
_BINARY = {"ADD": "{0}+{1}", "SUB": "{0}-{1}", "MUL": "{0}*{1}", "DIV": "{0}/{1}",
           "LT": "{0}<{1}", "LE": "{0}<={1}", "EQ": "{0}=={1}", "NE": "{0}!={1}",
           "AND": "{0}&&{1}", "OR": "{0}||{1}", "IF_ELSE_ZERO": "{0} ? {1} : 0",
           "POW": "pow({0},{1})", "CONSTPOW": "pow({0},{1})"}
_BINARY.update({op.upper(): op + "({0},{1})" for op in (
    "fmin", "fmax", "atan2", "fmod", "remainder", "hypot", "copysign")})


# glibc's sincos (bit for bit its sin and cos); elsewhere the two calls
_SINCOS = """#if defined(__GLIBC__)
extern void sincos(double, double*, double*);
#define UAVDYN_SINCOS(x, s, c) sincos(x, s, c)
#else
#define UAVDYN_SINCOS(x, s, c) (*(s) = sin(x), *(c) = cos(x))
#endif
"""


# glibc's vector library (2.35+, x86-64 AVX2): the lane operations it serves, by function name
_VECTOR = {"EXP": "exp", "LOG": "log", "SIN": "sin", "COS": "cos", "TAN": "tan",
           "ASIN": "asin", "ACOS": "acos", "ATAN": "atan", "SINH": "sinh", "COSH": "cosh",
           "TANH": "tanh", "ASINH": "asinh", "ACOSH": "acosh", "ATANH": "atanh",
           "ERF": "erf", "EXPM1": "expm1", "LOG1P": "log1p"}
_VECTOR_BINARY = {"ATAN2": "atan2", "HYPOT": "hypot", "POW": "pow", "CONSTPOW": "pow"}
# added to the compiler flags of vector-math code (linked whatever the linker's --as-needed)
VECTOR_FLAGS = ("-mavx2", "-Wl,--no-as-needed", "-lmvec")
GLIBC_VECTOR = (2, 35)  # the first glibc whose libmvec has atan2, tanh and hypot


@cache
def vector_math_unavailable() -> str | None:
    """Why ``vector_math`` cannot run here (None: it can): it needs an x86-64 CPU with AVX2,
    glibc 2.35 or later (its ``libmvec``) and a C compiler."""
    if platform.machine() not in ("x86_64", "AMD64"):
        return f"the CPU is {platform.machine()}, not x86-64"
    libc, version = platform.libc_ver()
    parts = tuple(int(v) for v in version.split(".")[:2] if v.isdigit())
    if libc != "glibc" or parts < GLIBC_VECTOR:
        return f"the C library is {libc or 'not glibc'} {version}, not glibc 2.35 or later"
    try:
        with open("/proc/cpuinfo") as fh:
            flags = next((line for line in fh if line.startswith("flags")), "")
    except OSError:
        flags = ""
    if "avx2" not in flags.split():
        return "the CPU has no AVX2"
    if find_compiler() is None:
        return "no C compiler was found"
    return None


def _vector_header() -> str:
    unary = "".join(f"__m256d _ZGVdN4v_{f}(__m256d);\n" for f in sorted(set(_VECTOR.values())))
    binary = "".join(f"__m256d _ZGVdN4vv_{f}(__m256d, __m256d);\n"
                     for f in sorted(set(_VECTOR_BINARY.values())))
    return "#include <immintrin.h>\n/* glibc's libmvec, four doubles a call */\n" + unary + binary


class LanesError(ValueError):
    """The Function cannot be written in lanes (not SX, or an operation without a C form)."""


def _constant(value: float) -> str:
    if math.isnan(value):
        return "NAN"
    if math.isinf(value):
        return "INFINITY" if value > 0 else "-INFINITY"
    return repr(float(value))


def lanes_c(func: ca.Function, name: str, lanes: int, vector_math: bool = False) -> str:
    """C of ``static void <name>(const casadi_real* const* arg, casadi_real* const* res)``:
    ``func`` for ``lanes`` cases at once, every input and output dense and lane-interleaved.

    Parameters
    ----------
    func : casadi.Function
        An SX Function (expand an MX one first).
    name : str
        Name of the C function.
    lanes : int
        Cases per call (4 suits 128- and 256-bit vector units).
    vector_math : bool
        The maths library's functions through ``libmvec`` (4 lanes; compile with
        :data:`VECTOR_FLAGS`): round-off agreement with the scalar code, not bitwise.

    Raises
    ------
    LanesError
        If ``func`` is not an SX Function or uses an operation this writer has no C for.
    """
    if not func.is_a("SXFunction"):
        raise LanesError(f"'{func.name()}' is not an SX Function; expand it first")
    if lanes < 1:
        raise LanesError(f"lanes must be >= 1, got {lanes}")
    if vector_math and lanes != 4:
        raise LanesError(f"vector_math needs 4 lanes (libmvec's AVX2 width), got {lanes}")
    loop = f"  for (b = 0; b < {lanes}; ++b) "
    pairs = {} if vector_math else _sin_cos_pairs(func)
    lines = [f"static void {name}(const casadi_real* const* arg, casadi_real* const* res) {{",
             f"  casadi_real w[{max(func.sz_w(), 1)}][{lanes}];", "  int b;"]
    if vector_math:
        lines.insert(0, _vector_header())
    if pairs:
        lines.insert(0, _SINCOS)
        lines.append(f"  casadi_real pair[{len(pairs) // 2}][{lanes}];")
    for k in range(func.n_instructions()):
        op = _NAMES.get(func.instruction_id(k), str(func.instruction_id(k)))
        ins, outs = func.instruction_input(k), func.instruction_output(k)
        operands = [f"w[{i}][b]" for i in ins]
        if vector_math and (op in _VECTOR or op in _VECTOR_BINARY):
            loads = ", ".join(f"_mm256_loadu_pd(w[{i}])" for i in ins)
            kind = "v" if op in _VECTOR else "vv"
            function = _VECTOR.get(op) or _VECTOR_BINARY[op]
            lines.append(f"  _mm256_storeu_pd(w[{outs[0]}], _ZGVdN4{kind}_{function}({loads}));")
            continue
        if k in pairs:
            first, slot = pairs[k]
            sin, cos = (f"&w[{outs[0]}][b]", f"&pair[{slot}][b]") if op == "SIN" else \
                (f"&pair[{slot}][b]", f"&w[{outs[0]}][b]")
            body = f"UAVDYN_SINCOS({operands[0]}, {sin}, {cos});" if first else \
                f"w[{outs[0]}][b] = pair[{slot}][b];"
        elif op == "INPUT":
            body = f"w[{outs[0]}][b] = arg[{ins[0]}][{ins[1]} * {lanes} + b];"
        elif op == "OUTPUT":
            body = f"res[{outs[0]}][{outs[1]} * {lanes} + b] = w[{ins[0]}][b];"
        elif op == "CONST":
            body = f"w[{outs[0]}][b] = {_constant(func.instruction_constant(k))};"
        elif op in _UNARY and len(ins) >= 1:
            body = f"w[{outs[0]}][b] = ({_UNARY[op].format(*operands)});"
        elif op in _BINARY and len(ins) == 2:
            body = f"w[{outs[0]}][b] = ({_BINARY[op].format(*operands)});"
        else:
            raise LanesError(f"'{func.name()}' uses the operation {op}, which has no lane C form")
        lines.append(loop + body)
    lines.append("}")
    return "\n".join(lines) + "\n"


def _sin_cos_pairs(func: ca.Function) -> dict[int, tuple[bool, int]]:
    """Instructions whose sine and cosine of one operand can share a ``sincos`` call:
    ``{instruction: (is the first of its pair, pair slot)}``. The second of a pair must read
    the same work element, unchanged since the first (CasADi reuses work elements)."""
    pending: dict[tuple[str, int], int] = {}  # (op, operand) -> instruction awaiting its partner
    pairs: dict[int, tuple[bool, int]] = {}
    for k in range(func.n_instructions()):
        op = _NAMES.get(func.instruction_id(k), "")
        ins, outs = func.instruction_input(k), func.instruction_output(k)
        if op in ("SIN", "COS") and outs[0] != ins[0]:
            partner = pending.pop(("COS" if op == "SIN" else "SIN", ins[0]), None)
            if partner is not None:
                slot = len(pairs) // 2
                pairs[partner], pairs[k] = (True, slot), (False, slot)
            else:
                pending.setdefault((op, ins[0]), k)
        if op != "OUTPUT":  # a write ends every pending pair that reads the element written
            for key in [key for key in pending if key[1] in outs[:1]]:
                del pending[key]
    return pairs
