"""The workspace's package.xml files: their package names and every dependency they list."""

import pathlib
import xml.etree.ElementTree as ET

REPO = pathlib.Path(__file__).resolve().parents[2]
DEPEND_TAGS = ('depend', 'build_depend', 'build_export_depend', 'buildtool_depend',
               'buildtool_export_depend', 'exec_depend', 'test_depend', 'doc_depend')


def manifests():
    return sorted(REPO.glob('abp_*/package.xml')) + sorted(REPO.glob('vendor/*/package.xml'))


def workspace_packages():
    return {ET.parse(path).getroot().findtext('name').strip() for path in manifests()}


def dependencies():
    """(package.xml path relative to the repo, tag, dependency) of every *depend entry."""
    out = []
    for path in manifests():
        root = ET.parse(path).getroot()
        for tag in DEPEND_TAGS:
            for element in root.iter(tag):
                out.append((str(path.relative_to(REPO)), tag, element.text.strip()))
    return out
