"""A model module that calls sys.exit at import (smgen and smtrain used to end silently with 7)."""

import sys

sys.exit(7)
