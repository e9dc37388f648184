"""The authors' VP2P-Match network (junshengzhou/VP2P-Match at be76104), module by module, under the authors' state
dict names so their checkpoint loads as it is."""
