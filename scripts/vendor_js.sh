#!/usr/bin/env bash
# Vendors the browser pages' npm dependencies into static/vendor/<package>@<version>/ at pinned
# versions, each tarball checked against its recorded SHA-256 before anything is unpacked.
# The vendored files are committed (the pages have no build step and fetch nothing from
# another origin); run this only to re-vendor or to add a package (then record its hash).
#   bash scripts/vendor_js.sh            re-vendor every package below
set -euo pipefail
cd "$(dirname "$0")/.."

# package | version | sha256 of the npm tarball | files to keep (globs in the tarball's package/;
# the licence, or package.json where it names the licence)
PACKAGES=(
  "@msgpack/msgpack|3.1.3|1fef5cd691fbe3ea2695ca12c8c01a5c2c50e7014486d32037e0242c1c24bd36|dist.esm/*.mjs dist.esm/utils/*.mjs LICENSE"
  "qrcode-generator|2.0.4|02e2e18a99a90b02dad940851f59b7c3c5fd1ab79cbdece8595cb06328878159|dist/qrcode.mjs package.json"
)

work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
listing=static/vendor/VENDORED.md
{
  echo "# Vendored browser dependencies"
  echo
  echo "Written by \`scripts/vendor_js.sh\` (npm tarballs at pinned versions, SHA-256 checked); do not edit."
  echo
  echo "| package | version | tarball sha256 | files |"
  echo "| --- | --- | --- | --- |"
} >"$work/VENDORED.md"

for entry in "${PACKAGES[@]}"; do
  IFS='|' read -r name version sha files <<<"$entry"
  echo "[vendor] $name@$version"
  (cd "$work" && npm pack --silent "$name@$version" >/dev/null)
  tarball="$work/$(echo "${name#@}" | tr '/' '-')-$version.tgz"
  got=$(sha256sum "$tarball" | cut -d' ' -f1)
  if [ "$got" != "$sha" ]; then
    echo "[vendor] $name@$version: tarball sha256 $got, expected $sha; refusing it" >&2
    exit 1
  fi
  dest="static/vendor/$(echo "${name#@}" | tr '/' '-')@$version"
  rm -rf "$dest" && mkdir -p "$dest" "$work/x"
  tar xzf "$tarball" -C "$work/x"
  kept=()
  for pattern in $files; do
    for path in "$work"/x/package/$pattern; do
      rel=${path#"$work/x/package/"}
      mkdir -p "$dest/$(dirname "$rel")"
      cp "$path" "$dest/$rel"
      kept+=("$rel")
    done
  done
  # Source maps are not shipped; drop the comments that point at them.
  find "$dest" -name '*.mjs' -exec sed -i '/^\/\/# sourceMappingURL=/d' {} +
  echo "| \`$name\` | $version | \`$sha\` | ${#kept[@]} files under \`${dest#static/}\` |" >>"$work/VENDORED.md"
  rm -rf "$work/x"
done
mv "$work/VENDORED.md" "$listing"
echo "[vendor] ok: $listing"
