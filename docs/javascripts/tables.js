// Tables on a narrow screen: label every body cell with its column's header (data-label), and
// turn a table wider than its column into one card per row (class "cards", styled in
// stylesheets/extra.css on screens up to 700 px), so that no value is ever cut off or hidden
// behind a scroll bar. Tables that already carry labels (the generated ones) keep them.
(function () {
  function layout() {
    var narrow = window.matchMedia("(max-width: 700px)").matches;
    document.querySelectorAll(".md-typeset table").forEach(function (table) {
      var heads = Array.prototype.map.call(table.querySelectorAll("thead th"), function (th) {
        return th.textContent.trim();
      });
      table.querySelectorAll("tbody tr").forEach(function (tr) {
        Array.prototype.forEach.call(tr.children, function (td, i) {
          if (heads[i] && !td.hasAttribute("data-label")) td.setAttribute("data-label", heads[i]);
        });
      });
      table.classList.remove("cards");
      if (!narrow) return;
      var box = table.closest(".md-typeset__scrollwrap") || table.parentElement;
      var column = table.closest(".md-content__inner") || box;
      if (table.scrollWidth > box.clientWidth + 1 || box.scrollWidth > box.clientWidth + 1 ||
          table.getBoundingClientRect().right > column.getBoundingClientRect().right + 1) table.classList.add("cards");
    });
  }
  if (typeof document$ !== "undefined") document$.subscribe(layout);
  else document.addEventListener("DOMContentLoaded", layout);
  window.addEventListener("resize", layout);
  window.addEventListener("load", function () {  // again once MathJax has typeset the cells' math
    layout();
    if (window.MathJax && MathJax.startup && MathJax.startup.promise) MathJax.startup.promise.then(layout);
  });
})();
