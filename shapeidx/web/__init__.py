"""``shapeidx serve``: the local web page and JSON API over a store (see docs/web.md).

    app.py       StoreService (the store in memory) and the Starlette application
    static/      the page: index.html, app.js, style.css
"""
