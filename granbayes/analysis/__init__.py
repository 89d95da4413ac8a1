"""What the analyses of the thesis's questions compute, reusable (public).

- :func:`cell_experiment`: the experiment of one cell (a command at one setting);
- :mod:`granbayes.analysis.maps`: misfit maps over a (k, c_d) grid, where each command's
  heights are fitted and the valley of equally good laws;
- :mod:`granbayes.analysis.optimal`: the best command settings under a posterior;
- :mod:`granbayes.analysis.mechanics`: added-mass impulse, actuator power, the rigid floor.

The scripts of ``analyses/`` use these, the figures of :mod:`granbayes.figures` and the
statistics of :mod:`granbayes.stats`.
"""

from . import maps, mechanics, optimal
from ._summaries import cell_experiment

__all__ = ["cell_experiment", "maps", "mechanics", "optimal"]
