"""Type stubs of the compiled half of the vfp package (python/src/lib.rs).

A *source* is a path, or ``(name, [(column, float64 bytes in native order | text cells)])``.
A *data* object carries ``columns``, ``chamber_base``, ``holdout_every``, ``derive_flow``,
``diff_half_width`` and ``deadband`` as attributes. Reports come back as JSON text; columns as
``(name, float64 bytes or None, text cells or None)``.
"""

from typing import Any, List, Optional, Sequence, Tuple, Union

Source = Union[str, Tuple[str, List[Tuple[str, Union[bytes, List[str]]]]]]
Columns = Tuple[List[Tuple[str, Optional[bytes], Optional[List[str]]]], List[str]]

def read_log(source: Source, data: Any) -> Columns: ...
def identify(
    source: Source,
    data: Any,
    chamber: Optional[int],
    families: Optional[List[str]],
    weights: Tuple[float, float, float],
    max_n: int,
    max_m: int,
    prune: int,
) -> str: ...
def diagnose(
    source: Source,
    data: Any,
    chamber: Optional[int],
    model: Optional[Tuple[int, int]],
    alpha: float,
    min_gain: float,
    effects: Optional[List[str]],
    validate: Optional[Source],
) -> Tuple[str, bytes, bytes]: ...
def force(
    ident: Source,
    test: Source,
    data: Any,
    shape: Tuple[int, int],
    area: List[float],
    smooth: int,
    augmented: bool,
) -> str: ...
def export(
    source: Source,
    data: Any,
    chamber: Optional[int],
    shape: Tuple[Optional[int], Optional[int]],
    p: int,
    all_samples: bool,
) -> List[Tuple[int, Optional[str], List[str], str]]: ...
def replay(
    model: str,
    model_name: str,
    source: Source,
    data: Any,
) -> Tuple[str, List[Tuple[str, Optional[bytes], Optional[List[str]]]]]: ...
def simulate(
    preset: str,
    cycles: Optional[int],
    flows: Optional[Sequence[float]],
    seed: Optional[int],
) -> Columns: ...
