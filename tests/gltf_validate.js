// Validate glTF files with the Khronos glTF-Validator (npm gltf-validator); prints one JSON
// report per file: {file, errors, warnings, infos, messages: [first 20 issues]}.
// Usage: NODE_PATH=$(npm root -g) node tests/gltf_validate.js FILE...
const fs = require("fs");
const path = require("path");
const validator = require("gltf-validator");

async function check(file) {
  const data = new Uint8Array(fs.readFileSync(file));
  const report = await validator.validateBytes(data, {
    uri: path.basename(file),
    maxIssues: 200,
    externalResourceFunction: (uri) => new Promise((resolve, reject) => {
      fs.readFile(path.join(path.dirname(file), decodeURIComponent(uri)),
        (err, buf) => (err ? reject(err.toString()) : resolve(new Uint8Array(buf))));
    }),
  });
  const issues = report.issues;
  return {file, errors: issues.numErrors, warnings: issues.numWarnings,
          infos: issues.numInfos,
          messages: issues.messages.slice(0, 20).map((m) => `${m.severity} ${m.code} ${m.pointer || ""}: ${m.message}`)};
}

(async () => {
  for (const f of process.argv.slice(2)) console.log(JSON.stringify(await check(f)));
})().catch((e) => { console.error(String(e)); process.exit(1); });
