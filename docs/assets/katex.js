// Render the math that pymdownx.arithmatex marks (\( ... \) inline, \[ ... \] display) with KaTeX,
// on every page load (mkdocs-material's instant navigation included).
document$.subscribe(({ body }) => {
  renderMathInElement(body, {
    delimiters: [
      { left: "\\(", right: "\\)", display: false },
      { left: "\\[", right: "\\]", display: true },
    ],
    ignoredClasses: ["highlight", "jp-OutputArea"],
  });
});
