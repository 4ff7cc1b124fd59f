#!/usr/bin/env python3
"""How the vendored schemas here were made (run by hand; CI only reads the results).

- kubernetes-v1.33/: the Kubernetes 1.33 "local-strict" JSON schemas of the kinds the manifests
  use and their shared _definitions.json, unmodified, from the PyPI package kubernetes-validate
  1.37.0 (Apache-2.0, LICENSE.kubernetes-validate; the schemas are generated from Kubernetes'
  OpenAPI, Apache-2.0).
- agones-1.61/: the openAPIV3Schema of Agones' Fleet and FleetAutoscaler CRDs from Agones'
  install/yaml/install.yaml (chart agones-1.61.0, Apache-2.0, LICENSE.agones), with apiVersion
  and kind pinned to the CRD's group/version and kind.

    pip download --no-deps kubernetes-validate==1.37.0 && python3 vendor.py WHEEL INSTALL_YAML
"""
import json
import sys
import zipfile

import yaml

KINDS = [
    "_definitions.json",
    "configmap-v1.json",
    "deployment-apps-v1.json",
    "ingress-networking-v1.json",
    "persistentvolumeclaim-v1.json",
    "poddisruptionbudget-policy-v1.json",
    "secret-v1.json",
    "service-v1.json",
    "serviceaccount-v1.json",
    "statefulset-apps-v1.json",
]

wheel, install = sys.argv[1], sys.argv[2]
with zipfile.ZipFile(wheel) as z:
    for kind in KINDS:
        data = z.read(f"kubernetes_validate/kubernetes-json-schema/v1.33.0-local-strict/{kind}")
        open(f"kubernetes-v1.33/{kind}", "wb").write(data)
    licence = [n for n in z.namelist() if n.endswith("licenses/LICENSE")][0]
    open("LICENSE.kubernetes-validate", "wb").write(z.read(licence))

for doc in yaml.safe_load_all(open(install)):
    if not doc or doc.get("kind") != "CustomResourceDefinition":
        continue
    kind = doc["spec"]["names"]["kind"]
    if kind not in ("Fleet", "FleetAutoscaler"):
        continue
    group = doc["spec"]["group"]
    for version in doc["spec"]["versions"]:
        schema = version["schema"]["openAPIV3Schema"]
        props = schema.setdefault("properties", {})
        props["apiVersion"] = {"type": "string", "enum": [f"{group}/{version['name']}"]}
        props["kind"] = {"type": "string", "enum": [kind]}
        schema["required"] = sorted(set(schema.get("required", [])) | {"apiVersion", "kind"})
        name = f"agones-1.61/{kind.lower()}-{group.split('.')[0]}-{version['name']}.json"
        json.dump(schema, open(name, "w"), indent=1, sort_keys=True)
