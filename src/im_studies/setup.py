from setuptools import find_packages, setup

package_name = 'im_studies'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='IM drive stack maintainers',
    maintainer_email='drive-stack@example.org',
    description='Studies on the drive: the thesis reproduction, the chapter studies, the Dask '
                'campaign and the README/docs generators.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'campaign = im_studies.entry:campaign',
            'efficiency_map = im_studies.entry:efficiency_map',
            'robust_study = im_studies.entry:robust_study',
        ],
    },
)
