"""Users' corrections of a result's labels, in versions: the edits (:mod:`.edits`) and what a
version's deliverables are made of (:mod:`.version`). Version 0 is the machine's own result."""
