import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from hypothesis import settings

# No example database in the source tree; failures print their example.
settings.register_profile("repo", database=None)
settings.load_profile("repo")
