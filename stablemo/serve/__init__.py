"""`stablemo serve`: a local web page and JSON API for generating motions interactively.

    stablemo serve                       # the demo's 1-step student (teacher selectable), http://127.0.0.1:7860
    stablemo serve --bundle bundles/my_model --port 8000

- `models.py`: the named bundles, each loaded once, and one generation job per request (checked
  JSON spec -> Pipeline.generate -> arrays), run by a single worker so requests queue;
- `api.py`: the FastAPI app (page, static files, /api/info, /api/generate, /api/download);
- `vendor.py`: copies three.js from its npm package into `static/vendor/` at setup time, so the
  page needs no network when it runs;
- `guard.py`: the checks every request passes before a route sees it (Host, Origin, JSON, size, nesting);
- `local.py`: the app on a loopback port inside this process (tests, load scripts);
- the command line is stablemo.cli.serve;
- `static/`: the page (HTML/JS/CSS written for StableMo; the vendored library is gitignored).
"""
