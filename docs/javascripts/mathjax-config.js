// MathJax 3 for pymdownx.arithmatex (generic mode). MathJax typesets the page when it loads;
// with mkdocs-material's instant navigation, later page switches re-typeset the new content.
// The first emission of document$ is the initial page, already typeset: clearing MathJax's
// caches then would drop the CSS of the rendered glyphs and leave the formulas blank.
window.MathJax = {
  tex: {
    inlineMath: [["\\(", "\\)"]],
    displayMath: [["\\[", "\\]"]],
    processEscapes: true,
    processEnvironments: true,
  },
  options: {
    ignoreHtmlClass: ".*|",
    processHtmlClass: "arithmatex",
  },
};

if (typeof document$ !== "undefined") {
  let initialPage = true;
  document$.subscribe(() => {
    if (initialPage) {
      initialPage = false;
      return;
    }
    if (window.MathJax && MathJax.typesetPromise) {
      MathJax.startup.output.clearCache();
      MathJax.typesetClear();
      MathJax.texReset();
      MathJax.typesetPromise();
    }
  });
}
