"""Pictures of parts and answers: thumbnails, histogram plots, result sheets.

    render.py      headless shaded thumbnails, primary rays cast with Embree
    thumbcache.py  thumbnails of files, cached on disk by content hash
    plot.py        the paper's Figure 3/4 layout (ALL, IN, OUT, MIXED), matplotlib Agg
    similarity.py  distances in words, calibrated on a store's distance distribution
    sheet.py       one self-contained HTML page of a query and its hits
"""
