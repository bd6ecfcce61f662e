"""thinfilm.scenes"""
