"""Synthetic endoscopy with exact ground truth: a seeded anatomy (`scene`), a camera path
(`trajectory`), a lens (`lens`), an exact ray caster (`raycast`), near-field shading
(`render`, `texture`), spoiled frames (`events`) and the case folder writer (`writer`);
`generate` puts them together. `endopipe synth` and the bench are its commands.
"""

from endopipe.synth.generate import SynthConfig, SynthSummary, generate_case
from endopipe.synth.writer import Layout

__all__ = ["Layout", "SynthConfig", "SynthSummary", "generate_case"]
