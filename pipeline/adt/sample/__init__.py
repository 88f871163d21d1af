"""ADT's sample: no synthetic world (ADT's files are read through projectaria-tools, which only
reads real recordings); ``excerpt`` says where the real ADT excerpt lies, the settings that fit its
two frames, and how to get ADT.
"""
