// Validate one .glb/.gltf file with the Khronos glTF Validator; print its report as JSON.
// Usage: node tests/validators/validate_gltf.js FILE    (exit 0 when validated, whatever it found)
"use strict";
const fs = require("fs");
const path = require("path");
const validator = require("gltf-validator");

const file = process.argv[2];
if (!file) {
  console.error("usage: node validate_gltf.js FILE");
  process.exit(2);
}
validator.validateBytes(new Uint8Array(fs.readFileSync(file)), {uri: path.basename(file), maxIssues: 1000})
  .then((report) => process.stdout.write(JSON.stringify(report) + "\n"))
  .catch((error) => {
    console.error(`gltf-validator failed on ${file}: ${error}`);
    process.exit(1);
  });
