"""What the caller got wrong: the one error type the library raises for its inputs, and
how its messages name the field to blame.

`InputError` carries a message of the form "field.path: what is wrong" where a field is to
blame (the service answers it as a 422 at that field, the command line as bad input);
anything else the library raises is its own fault. Request models refuse what their
schema and validators can see (pydantic's ValidationError, whose messages follow the same
form); InputError is what the library refuses beyond that: a state where the dynamics
overflow, a motion too fast to integrate, an argument of the wrong size, a computation
past its budget.

It is a ValueError, so that the checks shared by validators and computations raise it in
both (a validator turns a ValueError into a field error of its model), and so that code
catching ValueError keeps working; a plain ValueError is not an InputError.
"""

from __future__ import annotations

import re

_FIELD = re.compile(r"^(?P<path>[A-Za-z_]\w*(?:\.\w+)*): (?P<msg>.+)$", re.DOTALL)
_VALIDATOR_PREFIXES = ("Value error, ", "Assertion failed, ")


class InputError(ValueError):
    """An input the library refuses, "field.path: what is wrong" where a field is to blame."""


def located(message: str) -> tuple[list[str | int], str]:
    """The field path a message names and what it says of it: "states.3.q: needs 2 entries"
    -> (["states", 3, "q"], "needs 2 entries"); ([], message) when it names none. The
    prefix pydantic puts before a validator's message ("Value error, ") is dropped."""
    for prefix in _VALIDATOR_PREFIXES:
        message = message.removeprefix(prefix)
    match = _FIELD.match(message)
    if not match:
        return [], message
    return [int(p) if p.isdigit() else p for p in match["path"].split(".")], match["msg"]
