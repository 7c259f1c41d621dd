"""E_aff as stored, recomputed from the bundle's own graph: the deep check of ``craftc validate``
and ``craftc pack``.

Why: ``affordance_energy.npy`` is what the robot ranks by; the graph is what a KB author reviews,
diffs and explains (``craftc explain`` prints its paths). ``content.py`` checks E_aff's shape and
range at every load, but a bundle whose energies do not come from its graph (an energy form
relabelled in the manifest, an edited ``.npy`` resealed, a graph edited after the build) passes
those checks and ranks by numbers no path explains. Recomputing costs ~40 ms for 81 verbs x 628
objects and grows with the graph, so it runs where a bundle is checked or signed, not at every
start-up of a robot, which trusts what was validated and signed.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..grounding.energies import energy_from_graph
from .bundle import Bundle
from .errors import BundleError

#: E_aff is stored as float32 of the compiler's float64; another CPU's kernels may move the last
#: bits of the recomputation. A relabelled form or an edited weight moves values by far more.
ENERGY_TOLERANCE = 1e-5


def check_energy_matches_graph(bundle: Bundle, where: Path | None = None) -> None:
    """Raise ``BundleError`` naming the first verb–object pair whose stored E_aff is not what the
    bundle's graph gives in the manifest's form and tau (``energies.energy_from_graph``).
    ``where``: the bundle as the user named it (a package unpacked privately), for the message."""
    m = bundle.manifest
    recomputed = energy_from_graph(bundle.index, bundle.index.forbidden_pairs(), m.verbs, m.properties,
                                   m.objects, tau=m.energy.tau, form=m.energy.form)  # [V, O]
    gap = np.abs(recomputed.astype(np.float64) - bundle.energy.astype(np.float64))
    if gap.size == 0 or float(gap.max()) <= ENERGY_TOLERANCE:
        return
    v, o = np.unravel_index(int(np.argmax(gap)), gap.shape)
    raise BundleError(
        f"{(where or bundle.path) / 'affordance_energy.npy'}: E_aff({m.verbs[v]!r}, {m.objects[o]!r}) = "
        f"{float(bundle.energy[v, o]):.6g}, but graph.json gives {float(recomputed[v, o]):.6g} in the "
        f"manifest's form {m.energy.form!r} (tau {m.energy.tau:g}); {int((gap > ENERGY_TOLERANCE).sum())} "
        "pairs differ: the energies are not this graph's — rebuild the bundle with craftc"
    )
