"""The subset of the Turbo PMAC command and PLC language that the emulator interprets.

Used by :mod:`.emulator` for on-line assignments (``P1=P1+1``) and for PLC programs
downloaded with ``OPEN PLC n CLEAR`` ... ``CLOSE`` (Turbo PMAC Software Reference,
"Program Command Specification"; Turbo PMAC User Manual, "Writing a PLC Program"). The
subset is what a rail driver needs, and no more; anything outside it is refused with
``ERR003`` at download, so a wrong program fails on the emulator rather than on the card:

- constants: decimal (``12``, ``-0.5``, ``.25``) and hexadecimal (``$20000``); no exponent
  (the manual's ``{constant}`` has no exponent form, and ``E`` is not part of a number);
- variables ``Pn``, ``Qn``, ``Mn``, ``In`` (n = 0..8191);
- expressions with ``+ - * /`` and parentheses, evaluated left to right within a
  precedence level (``*`` and ``/`` before ``+`` and ``-``);
- conditions ``(expr op expr [AND|OR expr op expr]...)`` with ``op`` one of ``= != > < !>
  !<``, combined strictly left to right;
- statements: ``var=expr``, ``IF (cond)`` / ``ELSE`` / ``ENDIF`` (``ENDI``), and
  ``CMD"text"`` (an on-line command issued by the program), several per line.

Spaces are removed before parsing (outside ``CMD`` strings), as the card ignores them.
No ROS, no sockets: plain functions over a :class:`VarStore`.
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Callable, Protocol

__all__ = ["PlcSyntaxError", "VarStore", "parse_constant", "Expr", "parse_expression",
           "parse_condition", "compile_line", "PlcProgram", "squeeze", "VAR_MAX"]

VAR_MAX = 8191

_TOKEN = re.compile(r"""
    (?P<hex>\$[0-9A-F]+)
  | (?P<num>\d+\.?\d*|\.\d+)
  | (?P<var>[PQMI]\d+)
  | (?P<logic>AND|OR)
  | (?P<cmp>!=|!>|!<|=|>|<)
  | (?P<op>[-+*/()])
""", re.VERBOSE)


class PlcSyntaxError(ValueError):
    """Text the card would refuse (ERR003)."""


class VarStore(Protocol):
    def get(self, kind: str, n: int) -> float: ...

    def set(self, kind: str, n: int, value: float) -> None: ...


def squeeze(text: str) -> str:
    """Upper case without blanks, except inside double-quoted strings (CMD"...")."""
    out, quoted = [], False
    for ch in text:
        if ch == '"':
            quoted = not quoted
            out.append(ch)
        elif quoted:
            out.append(ch)
        elif not ch.isspace():
            out.append(ch.upper())
    return "".join(out)


def parse_constant(text: str, i: int = 0) -> tuple[float, int]:
    """A signed decimal or ``$hex`` constant at ``text[i:]``; returns (value, end)."""
    sign, j = 1.0, i
    if j < len(text) and text[j] in "+-":
        sign, j = (-1.0 if text[j] == "-" else 1.0), j + 1
    m = _TOKEN.match(text, j)
    if m is None or m.lastgroup not in ("hex", "num"):
        raise PlcSyntaxError(f"constant expected at {text[i:]!r}")
    value = float(int(m.group(0)[1:], 16)) if m.lastgroup == "hex" else float(m.group(0))
    end = m.end()
    if end < len(text) and text[end] == "E" and end + 1 < len(text) and \
            (text[end + 1].isdigit() or text[end + 1] in "+-"):
        raise PlcSyntaxError(f"exponent not accepted in {text[i:end + 2]!r}")
    return sign * value, end


Expr = Callable[[VarStore], float]


def _var_ref(token: str) -> tuple[str, int]:
    n = int(token[1:])
    if n > VAR_MAX:
        raise PlcSyntaxError(f"{token}: variable number beyond {VAR_MAX}")
    return token[0], n


class _Parser:
    def __init__(self, text: str, i: int) -> None:
        self.s, self.i = text, i

    def peek(self) -> tuple[str | None, str]:
        m = _TOKEN.match(self.s, self.i)
        return (m.lastgroup, m.group(0)) if m else (None, "")

    def take(self) -> tuple[str | None, str]:
        m = _TOKEN.match(self.s, self.i)
        if m is None:
            raise PlcSyntaxError(f"unexpected {self.s[self.i:]!r}")
        self.i = m.end()
        return m.lastgroup, m.group(0)

    def expr(self) -> Expr:
        left = self.term()
        while self.peek()[1] in ("+", "-"):
            op = self.take()[1]
            left = _binary(op, left, self.term())
        return left

    def term(self) -> Expr:
        left = self.factor()
        while self.peek()[1] in ("*", "/"):
            op = self.take()[1]
            left = _binary(op, left, self.factor())
        return left

    def factor(self) -> Expr:
        kind, tok = self.peek()
        if tok == "-":
            self.take()
            inner = self.factor()
            return lambda v: -inner(v)
        if tok == "(":
            self.take()
            inner = self.expr()
            if self.take()[1] != ")":
                raise PlcSyntaxError("missing )")
            return inner
        if kind in ("hex", "num"):
            value, self.i = parse_constant(self.s, self.i)
            return lambda v: value
        if kind == "var":
            self.take()
            ref = _var_ref(tok)
            return lambda v: v.get(*ref)
        raise PlcSyntaxError(f"operand expected at {self.s[self.i:]!r}")

    def comparison(self) -> Callable[[VarStore], bool]:
        a = self.expr()
        kind, op = self.take()
        if kind != "cmp":
            raise PlcSyntaxError(f"comparison expected, got {op!r}")
        b = self.expr()
        test = {"=": lambda x, y: x == y, "!=": lambda x, y: x != y,
                ">": lambda x, y: x > y, "<": lambda x, y: x < y,
                "!>": lambda x, y: not x > y, "!<": lambda x, y: not x < y}[op]
        return lambda v: test(a(v), b(v))

    def condition(self) -> Callable[[VarStore], bool]:
        if self.take()[1] != "(":
            raise PlcSyntaxError("condition must be in parentheses")
        cond = self.comparison()
        while self.peek()[0] == "logic":
            word = self.take()[1]
            nxt, prev = self.comparison(), cond
            cond = ((lambda v, p=prev, q=nxt: p(v) and q(v)) if word == "AND"
                    else (lambda v, p=prev, q=nxt: p(v) or q(v)))
        if self.take()[1] != ")":
            raise PlcSyntaxError("missing ) after condition")
        return cond


def _binary(op: str, a: Expr, b: Expr) -> Expr:
    if op == "+":
        return lambda v: a(v) + b(v)
    if op == "-":
        return lambda v: a(v) - b(v)
    if op == "*":
        return lambda v: a(v) * b(v)

    def div(v: VarStore) -> float:
        d = b(v)
        return a(v) / d if d else 0.0
    return div


def parse_expression(text: str, i: int = 0) -> tuple[Expr, int]:
    """An expression at ``text[i:]`` (squeezed text); returns (evaluator, end)."""
    p = _Parser(text, i)
    return p.expr(), p.i


def parse_condition(text: str, i: int = 0) -> tuple[Callable[[VarStore], bool], int]:
    p = _Parser(text, i)
    return p.condition(), p.i


# -- PLC programs -------------------------------------------------------------------------
@dataclass
class _Op:
    kind: str                          # assign | if | else | endif | cmd
    target: tuple[str, int] | None = None
    expr: Expr | None = None
    cond: Callable[[VarStore], bool] | None = None
    text: str = ""
    jump: int = -1                     # if: to else+1/endif+1; else: to endif+1


_RE_ASSIGN = re.compile(r"([PQMI]\d+)=")
_RE_CMD = re.compile(r'CMD"([^"]*)"')


def compile_line(line: str) -> list[_Op]:
    """The statements of one program line (squeezed); PlcSyntaxError if outside the subset."""
    s, i, ops = squeeze(line), 0, []
    while i < len(s):
        if s.startswith("IF(", i):
            cond, i = parse_condition(s, i + 2)
            ops.append(_Op("if", cond=cond))
            continue
        if s.startswith("ELSE", i):
            ops.append(_Op("else"))
            i += 4
            continue
        for word in ("ENDIF", "ENDI"):
            if s.startswith(word, i):
                ops.append(_Op("endif"))
                i += len(word)
                break
        else:
            m = _RE_CMD.match(s, i)
            if m:
                ops.append(_Op("cmd", text=m.group(1)))
                i = m.end()
                continue
            m = _RE_ASSIGN.match(s, i)
            if m is None:
                raise PlcSyntaxError(f"statement not in the emulated PLC subset: {s[i:]!r}")
            expr, i = parse_expression(s, m.end())
            ops.append(_Op("assign", target=_var_ref(m.group(1)), expr=expr))
    return ops


@dataclass
class PlcProgram:
    """A PLC buffer: its source lines (for LIST) and the compiled statements."""

    number: int
    lines: list[str] = field(default_factory=list)
    ops: list[_Op] = field(default_factory=list)
    enabled: bool = False
    scans: int = 0

    def add_line(self, line: str) -> None:
        """Compile and append one line (PlcSyntaxError leaves the buffer unchanged)."""
        new = compile_line(line)
        self.lines.append(line.strip().upper())
        self.ops.extend(new)
        self._link()

    def clear(self) -> None:
        self.lines.clear()
        self.ops.clear()

    def _link(self) -> None:
        stack: list[int] = []
        for k, op in enumerate(self.ops):
            if op.kind == "if":
                stack.append(k)
            elif op.kind == "else":
                if not stack or self.ops[stack[-1]].kind != "if":
                    continue            # structure checked by check_structure()
                self.ops[stack.pop()].jump = k + 1
                stack.append(k)
            elif op.kind == "endif" and stack:
                self.ops[stack.pop()].jump = k + 1

    def check_structure(self) -> None:
        """Raise PlcSyntaxError unless every IF has its ENDIF (ERR009 on the card)."""
        depth = 0
        for op in self.ops:
            if op.kind == "if":
                depth += 1
            elif op.kind in ("else", "endif"):
                if depth == 0:
                    raise PlcSyntaxError(f"{op.kind.upper()} without IF")
                if op.kind == "endif":
                    depth -= 1
        if depth:
            raise PlcSyntaxError("IF without ENDIF")

    def scan(self, store: VarStore, command: Callable[[str], None]) -> None:
        """Run the program once from the top (one PLC scan)."""
        self.scans += 1
        k, n = 0, len(self.ops)
        while k < n:
            op = self.ops[k]
            if op.kind == "assign":
                store.set(*op.target, op.expr(store))
            elif op.kind == "cmd":
                command(op.text)
            elif op.kind == "if":
                if not op.cond(store):
                    k = op.jump
                    continue
            elif op.kind == "else":
                k = op.jump
                continue
            k += 1
