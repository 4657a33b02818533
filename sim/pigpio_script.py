# pigpiod's scripts for the emulator: the script text parsed, and run on a thread of its own.
from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass, field

PI_BAD_SCRIPT, PI_BAD_PARAM_NUM, PI_DUP_TAG = -47, -52, -53
PI_BAD_SCRIPT_CMD, PI_BAD_VAR_NUM, PI_NOT_HALTED, PI_BAD_TAG = -55, -56, -62, -63
PI_SCRIPT_INITING, PI_SCRIPT_HALTED, PI_SCRIPT_RUNNING = 0, 1, 2
MAX_PARAMS, MAX_VARS = 10, 150

#: script-only commands (flow, the accumulator A, the flag F) and their operand counts
FLOW = {"tag": 1, "mils": 1, "dcr": 1, "inr": 1, "jp": 1, "jm": 1, "jz": 1, "jnz": 1,
        "jmp": 1, "ld": 2, "lda": 1, "cmp": 1, "halt": 0}
#: pigpiod commands a script may give (those the emulator's outputs honour): name -> operands
GPIO = {"w": 2, "pwm": 2, "hp": 3}

#: runs one GPIO command (name, operands) on the bank; returns its result (A and F)
Gpio = Callable[[str, list[int]], int]


@dataclass(frozen=True)
class Operand:
    """A number, a variable ``vN`` or a parameter ``pN``."""

    kind: str  # "n", "v" or "p"
    value: int


@dataclass(frozen=True)
class Instr:
    name: str
    operands: tuple[Operand, ...]


@dataclass
class Script:
    """A stored script: its instructions, tags, parameters and variables, and its thread."""

    instrs: list[Instr]
    tags: dict[int, int]
    params: list[int] = field(default_factory=lambda: [0] * MAX_PARAMS)
    variables: list[int] = field(default_factory=lambda: [0] * MAX_VARS)
    state: int = PI_SCRIPT_HALTED
    halt: threading.Event = field(default_factory=threading.Event)
    thread: threading.Thread | None = None


def parse(text: str) -> Script | int:
    """The script, or the pigpio error code pigpiod answers PROC with."""
    words = text.split()
    instrs: list[Instr] = []
    tags: dict[int, int] = {}
    index = 0
    while index < len(words):
        name = words[index].lower()
        count = FLOW.get(name, GPIO.get(name))
        if count is None:
            return PI_BAD_SCRIPT_CMD
        if index + 1 + count > len(words):
            return PI_BAD_SCRIPT
        operands = [_operand(word) for word in words[index + 1:index + 1 + count]]
        index += 1 + count
        if any(isinstance(op, int) for op in operands):
            return next(op for op in operands if isinstance(op, int))
        ops = tuple(op for op in operands if isinstance(op, Operand))
        if name in ("dcr", "inr", "ld") and ops[0].kind == "n":
            return PI_BAD_VAR_NUM  # only a variable or a parameter can be changed
        if name == "tag":
            if ops[0].value in tags:
                return PI_DUP_TAG
            tags[ops[0].value] = len(instrs)
            continue
        instrs.append(Instr(name, ops))
    for instr in instrs:
        if instr.name.startswith("j") and instr.operands[0].value not in tags:
            return PI_BAD_TAG
    return Script(instrs, tags)


def _operand(word: str) -> Operand | int:
    kind = word[:1].lower()
    if kind in ("v", "p"):
        try:
            number = int(word[1:])
        except ValueError:
            return PI_BAD_SCRIPT
        limit = MAX_VARS if kind == "v" else MAX_PARAMS
        if not 0 <= number < limit:
            return PI_BAD_VAR_NUM if kind == "v" else PI_BAD_PARAM_NUM
        return Operand(kind, number)
    try:
        return Operand("n", int(word, 0))
    except ValueError:
        return PI_BAD_SCRIPT


def run(script: Script, gpio: Gpio, lock: threading.RLock) -> None:
    """Execute from the top until HALT, the end, or a stop request (PROCS)."""
    a = f = pc = 0
    halt = script.halt
    while pc < len(script.instrs) and not halt.is_set():
        instr = script.instrs[pc]
        values = [_value(script, op) for op in instr.operands]
        name = instr.name
        pc += 1
        if name == "mils":
            if halt.wait(values[0] / 1000.0):
                break
            continue
        with lock:
            if name in GPIO:
                a = f = gpio(name, values)
            elif name == "ld":
                _store(script, instr.operands[0], values[1])  # F stays
            elif name in ("dcr", "inr"):
                f = _store(script, instr.operands[0], values[0] + (1 if name == "inr" else -1))
            elif name == "lda":
                a = values[0]
            elif name == "cmp":
                f = a - values[0]
            elif name == "halt":
                break
            elif _jumps(name, f):
                pc = script.tags[instr.operands[0].value]


def _jumps(name: str, f: int) -> bool:
    return {"jmp": True, "jp": f >= 0, "jm": f < 0, "jz": f == 0, "jnz": f != 0}.get(name, False)


def _value(script: Script, op: Operand) -> int:
    if op.kind == "v":
        return script.variables[op.value]
    if op.kind == "p":
        return script.params[op.value]
    return op.value


def _store(script: Script, op: Operand, value: int) -> int:
    value = (value + 2**31) % 2**32 - 2**31  # a C int
    if op.kind == "v":
        script.variables[op.value] = value
    elif op.kind == "p":
        script.params[op.value] = value
    return value


PI_BAD_SCRIPT_ID, PI_NO_SCRIPT_ROOM, PI_TOO_MANY_PARAM = -48, -57, -61
MAX_SCRIPTS = 32


class ScriptHost:
    """pigpiod's script slots: PROC stores, PROCR runs (with parameters), PROCU updates the
    parameters of a stored or running script, PROCP reports, PROCS stops, PROCD deletes."""

    def __init__(self, gpio: Gpio, lock: threading.RLock) -> None:
        self.gpio = gpio
        self.lock = lock
        self.scripts: dict[int, Script] = {}

    def store(self, text: bytes) -> int:
        parsed = parse(text.decode("latin-1"))
        if isinstance(parsed, int):
            return parsed
        free = [i for i in range(MAX_SCRIPTS) if i not in self.scripts]
        if not free:
            return PI_NO_SCRIPT_ROOM
        self.scripts[free[0]] = parsed
        return free[0]

    def run(self, script_id: int, params: bytes) -> int:
        script = self.scripts.get(script_id)
        if script is None:
            return PI_BAD_SCRIPT_ID
        if script.state == PI_SCRIPT_RUNNING:
            return PI_NOT_HALTED
        if (error := self._set_params(script, params)) < 0:
            return error
        script.halt.clear()
        script.state = PI_SCRIPT_RUNNING
        script.thread = threading.Thread(target=self._run, args=(script,), daemon=True,
                                         name=f"pigpiod-script-{script_id}")
        script.thread.start()
        return 0

    def _run(self, script: Script) -> None:
        try:
            run(script, self.gpio, self.lock)
        finally:
            script.state = PI_SCRIPT_HALTED

    def update(self, script_id: int, params: bytes) -> int:
        script = self.scripts.get(script_id)
        return PI_BAD_SCRIPT_ID if script is None else self._set_params(script, params)

    def _set_params(self, script: Script, params: bytes) -> int:
        count = len(params) // 4
        if count > MAX_PARAMS:
            return PI_TOO_MANY_PARAM
        with self.lock:
            for i in range(count):
                value = int.from_bytes(params[4 * i:4 * i + 4], "little")
                script.params[i] = value - 2**32 if value >= 2**31 else value
        return 0

    def status(self, script_id: int) -> tuple[int, bytes]:
        """PROCP: the byte count of the answer (11 ints: state, then p0-p9) and the bytes."""
        script = self.scripts.get(script_id)
        if script is None:
            return PI_BAD_SCRIPT_ID, b""
        values = [script.state, *script.params]
        return 44, b"".join((v & 0xFFFFFFFF).to_bytes(4, "little") for v in values)

    def stop(self, script_id: int) -> int:
        script = self.scripts.get(script_id)
        if script is None:
            return PI_BAD_SCRIPT_ID
        script.halt.set()
        return 0

    def delete(self, script_id: int) -> int:
        if self.stop(script_id) < 0:
            return PI_BAD_SCRIPT_ID
        self.scripts.pop(script_id)
        return 0

    def stop_all(self) -> None:
        for script in self.scripts.values():
            script.halt.set()
