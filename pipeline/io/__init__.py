"""Reading and writing files on any Beam filesystem: atomic writes and bounded reads (``files``), remote
storage options (``storage``), untrusted ``.npz`` files read without pickle (``npz_reader``,
``clip_reader``) and the queries of existing clips (``given_queries``)."""
