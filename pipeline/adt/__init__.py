"""Aria Digital Twin clips, as the TAPVid-3D release built them: reader (projectaria-tools), units
(listing and naming its units), rectify (pinhole re-rendering and the upright rotation), annotate
(the group entry), tracks (one chunk's candidate clip), source (its Source), sample (where the real
excerpt lies), bench (its benchmark entry)."""
