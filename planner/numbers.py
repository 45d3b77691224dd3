"""Number types of request schemas: only a JSON number gives a number.

pydantic's lax mode reads "0.1" as 0.1 and true as 1.0; `Real` refuses strings and
booleans (an integer is still a real), `Count` accepts integers only. Both document as a
plain JSON `number` / `integer`.
"""

from __future__ import annotations

from typing import Annotated

from pydantic import Strict

Real = Annotated[float, Strict()]
"""A real number, given as a JSON number."""
Count = Annotated[int, Strict()]
"""A whole number, given as a JSON integer."""
