"""Pages in a browser, drawn from result objects: one run (:mod:`~online_id.report.run_page`,
``online-id report``), a live ``listen`` (:mod:`~online_id.report.live`, ``listen --web``) and a fleet of
logs (:mod:`~online_id.report.fleet`, ``batch``'s ``index.html``). :mod:`~online_id.report.page` holds what
they share (plotly.js inside the page, tables, thinning). Nothing here computes an estimate: the
workflows do, and these functions only draw what they return."""
