"""The authors' VP2P-Match network (junshengzhou/VP2P-Match at be76104), module by module, under the authors' state
dict names so their checkpoint loads as it is; their pixels, points and inference as stages (stages.py, prepare.py),
the import of their checkpoint (importer.py) and the forward on a reference folder (reference.py): the method's
`official` variant."""
