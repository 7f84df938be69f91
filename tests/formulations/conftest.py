import sys
from pathlib import Path

# brute_force.py and tiny.py are helpers of these tests, imported by name.
sys.path.insert(0, str(Path(__file__).parent))
