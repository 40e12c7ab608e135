#!/usr/bin/env bash
# Rebuilds hack_render/export/viewer_static/three.bundle.min.js: three.js (MIT, see
# LICENSE-three.js.txt beside it) with GLTFLoader, OrbitControls and RoomEnvironment,
# bundled into one ES module by esbuild, both from the npm registry. The viewer loads
# nothing else, so `hack-render view` needs no network. Run from the repository root.
set -euo pipefail
THREE_VERSION=0.187.0
out="$(pwd)/hack_render/export/viewer_static"
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
cd "$work"
echo '{"name": "vendor", "private": true, "version": "0.0.0"}' > package.json
npm install --no-audit --no-fund "three@${THREE_VERSION}" esbuild@0.25 >/dev/null
cat > entry.js <<'JS'
export * from 'three';
export { GLTFLoader } from 'three/examples/jsm/loaders/GLTFLoader.js';
export { OrbitControls } from 'three/examples/jsm/controls/OrbitControls.js';
export { RoomEnvironment } from 'three/examples/jsm/environments/RoomEnvironment.js';
JS
./node_modules/.bin/esbuild entry.js --bundle --format=esm --minify --legal-comments=inline \
  --outfile="$out/three.bundle.min.js"
cp node_modules/three/LICENSE "$out/LICENSE-three.js.txt"
echo "three.js ${THREE_VERSION} -> $out/three.bundle.min.js"
