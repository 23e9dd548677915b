"""Numbers as JSON writes them, taken without coercion.

pydantic's default (lax) mode reads ``false`` as 0.0, ``true`` as 1, ``"12.5"``
as 12.5 and ``2.0`` as the integer 2: a wrong value in a request, a schedule
or a setup file then becomes a plausible number and is used (a calibration
``valid_to_unix_s: false`` was stored as valid until 1970). The types here
refuse them with pydantic's usual message ("Input should be a valid
number"): ``Number`` takes a JSON integer or fraction, finite; ``Integer``
an integer only. Each field adds its bounds (``Field(ge=..., le=...)``).
"""

from __future__ import annotations

from typing import Annotated

from pydantic import Field, Strict

#: A finite JSON number (an integer or a fraction); not a boolean, not a string.
Number = Annotated[float, Strict(), Field(allow_inf_nan=False)]
#: A JSON integer; not a boolean, not a fraction (``2.0``), not a string.
Integer = Annotated[int, Strict()]
