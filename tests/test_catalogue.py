"""The shipped models' catalogue (``diffsampler list``, README's model table) is what
benchmarks/catalogue.py makes from the cards and the reports: it cannot drift."""
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

import catalogue  # noqa: E402


def test_catalogue_matches_the_cards_and_reports():
    stored = json.loads(catalogue.CATALOGUE.read_text())
    assert stored == catalogue.catalogue(), "rerun python benchmarks/catalogue.py"


def test_readme_table_is_the_catalogue():
    stored = json.loads(catalogue.CATALOGUE.read_text())
    readme = catalogue.README.read_text()
    assert catalogue.with_table(readme, catalogue.readme_table(stored)) == readme


def test_every_shipped_model_has_its_figures():
    for name, entry in json.loads(catalogue.CATALOGUE.read_text()).items():
        assert entry["ms_per_set_1024"] is not None, name
        assert entry["spectrum_mae_1024"] is not None, name
