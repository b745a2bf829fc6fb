"""The documentation site works without a network: MathJax is served with it, and the build refuses a page
that loads a script or style from another host (``make docs`` builds it; this checks the pieces)."""
from __future__ import annotations

import importlib.util
import runpy
from pathlib import Path
from types import SimpleNamespace

import pytest

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def conf():
    pytest.importorskip("sphinx", reason="the docs extra is not installed")
    return runpy.run_path(str(ROOT / "docs" / "conf.py"))


def test_mathjax_comes_from_the_site_not_a_cdn(conf):
    assert "sphinx-mathjax-offline" in conf["extensions"]
    spec = importlib.util.find_spec("sphinx-mathjax-offline")
    assert spec is not None and spec.origin is not None, "pip install the docs extra"
    mathjax = Path(spec.origin).parent / "static" / "mathjax"
    assert (mathjax / "tex-chtml.js").is_file()
    assert any((mathjax / "output" / "chtml" / "fonts" / "woff-v2").glob("*.woff"))   # fonts served too
    assert "mathjax_path" not in conf                                                    # no CDN address set


def test_the_build_refuses_a_page_that_loads_from_the_network(conf, tmp_path):
    page = tmp_path / "guide" / "page.html"
    page.parent.mkdir()
    nav = '<nav><p class="bd-links__title">Section Navigation</p><a href="x.html">x</a></nav>'
    page.write_text(f'<html><script src="_static/mathjax/tex-chtml.js"></script>{nav}</html>')
    app = SimpleNamespace(outdir=str(tmp_path), builder=SimpleNamespace(format="html"))
    conf["_check_pages"](app, None)                                  # a local script and a working nav pass
    page.write_text(f'<html><script src="https://cdn.jsdelivr.net/npm/mathjax@3/es5/tex-chtml.js"></script>{nav}'
                    '</html>')
    with pytest.raises(RuntimeError, match="loads a script or style from the network"):
        conf["_check_pages"](app, None)
    page.write_text('<html><nav><p class="bd-links__title">Section Navigation</p></nav></html>')
    with pytest.raises(RuntimeError, match="its section navigation lists no page"):
        conf["_check_pages"](app, None)
