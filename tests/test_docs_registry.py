"""docs/runtime.md lists the finishing steps as the registry has them (it cannot drift)."""
from pathlib import Path

from diffsampler_rt.finish.pipeline import markdown_table


def test_runtime_docs_list_the_registered_steps():
    text = (Path(__file__).parent.parent / "docs" / "runtime.md").read_text()
    block = text.split("<!-- steps:begin -->\n")[1].split("\n<!-- steps:end -->")[0]
    assert block == markdown_table(), "regenerate the table: markdown_table()"
