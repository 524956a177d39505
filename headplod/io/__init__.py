"""Reading and writing the files of the headplod contract.

Transitional step of the split of ``headplod/io.py`` into a package: the
module moved unchanged to ``_storage.py`` and is re-exported here.
"""

from ._storage import *  # noqa: F401,F403
from ._storage import __all__  # noqa: F401
