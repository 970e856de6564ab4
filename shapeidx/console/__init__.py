"""What the command line needs beyond click, importable without numpy, h5py or Embree.

    exits.py    the exit-status table and how every error becomes one line and one status
    params.py   option types that refuse NaN, infinities and negative values; light defaults
    output.py   ``--format table|csv|tsv|json|jsonl``; a closed pipe ends the command quietly
    queries.py  what ``shapeidx query`` takes: files, directories, ``-`` (standard input)

``shapeidx --version`` and ``--help`` import only this room and click (see
tests/test_startup.py); each command imports the library it needs when it runs.
"""
